"""The world, the expert and the GR field read the one robot/sensor spec."""

import re

import pytest

from vla_gr.core.gr_field import GRFieldConfig
from vla_gr.envs import expert, geodesic
from vla_gr.envs import robot as rb
from vla_gr.geometry import robot_spec


def test_robot_model_is_built_from_the_spec():
    xml = rb.robot_body_xml(64, 64)
    size = re.search(r'name="robot_base" type="cylinder" size="([\d.]+) ', xml)
    assert float(size.group(1)) == robot_spec.ROBOT_RADIUS
    cam = re.search(r'name="robot_camera" pos="0 0 ([\d.]+)"', xml)
    assert float(cam.group(1)) == robot_spec.CAMERA_HEIGHT
    fovy = float(re.search(r'fovy="([\d.]+)"', xml).group(1))
    assert fovy == pytest.approx(rb.vertical_fov_deg(robot_spec.HFOV_DEG, 64, 64), abs=1e-5)


def test_ground_truth_expert_and_field_share_the_radius():
    assert geodesic.ROBOT_RADIUS is robot_spec.ROBOT_RADIUS
    assert expert.ROBOT_RADIUS is robot_spec.ROBOT_RADIUS
    assert GRFieldConfig().robot_radius == robot_spec.ROBOT_RADIUS


def test_env_scales_actions_by_the_spec_speeds():
    from vla_gr.envs import nav_env

    assert nav_env.MAX_LINEAR_SPEED == robot_spec.MAX_LINEAR_SPEED
    assert nav_env.MAX_ANGULAR_SPEED == robot_spec.MAX_ANGULAR_SPEED
