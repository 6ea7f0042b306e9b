"""Renderer and robot on a hand-written MJCF room: metric depth, segmentation, kinematics."""

import math

import mujoco
import numpy as np
import pytest

from vla_gr.envs import robot as rb
from vla_gr.envs.rendering import (
    RGBDRenderer,
    geom_instance_ids,
    linearize_depth,
    make_gl_context,
    tune_model_for_speed,
)

WALL_X = 3.0  # inner face of the east wall


def room_xml(size: int) -> str:
    """A 6 x 6 m room: east wall face at x = 3, a red box 'obj7' at (-2, 0), robot at origin."""
    return f"""<mujoco><worldbody>
      <light pos="0 0 3" dir="0 0 -1" castshadow="false"/>
      <geom name="floor" type="box" size="4 4 0.01" pos="0 0 -0.01" rgba=".6 .6 .6 1"/>
      <geom name="wall_e" type="box" size="0.05 4 1.25" pos="{WALL_X + 0.05} 0 1.25"/>
      <geom name="wall_n" type="box" size="4 0.05 1.25" pos="0 3.05 1.25"/>
      <body name="obj7">
        <geom name="obj7_seat" type="box" size="0.2 0.2 0.25" pos="-2 0 0.25" rgba="1 0 0 1"/>
      </body>
      {rb.robot_body_xml(size, size)}
    </worldbody></mujoco>"""


@pytest.fixture(scope="module")
def world():
    size = 64
    spec = mujoco.MjSpec.from_string(room_xml(size))
    rb.add_robot_actuators(spec)
    model = spec.compile()
    handles = rb.configure_robot(model, control_hz=10.0, substeps=5)
    tune_model_for_speed(model, size, size)
    data = mujoco.MjData(model)
    gl = make_gl_context(size, size)
    renderer = RGBDRenderer(model, gl, size, size, handles.camera_id, max_depth=10.0)
    yield model, data, handles, renderer
    renderer.close()
    gl.free()


# ----------------------------------------------------------------------------- pure maths


def test_vertical_fov_square_and_wide():
    assert rb.vertical_fov_deg(79.0, 64, 64) == pytest.approx(79.0)
    fovy = rb.vertical_fov_deg(90.0, 200, 100)  # tan(45) * 1/2 = 0.5
    assert fovy == pytest.approx(2 * math.degrees(math.atan(0.5)))
    with pytest.raises(ValueError, match="hfov_deg"):
        rb.vertical_fov_deg(180.0, 64, 64)


def test_wrap_angle_range():
    angles = np.array([math.pi, -math.pi, 3 * math.pi, 0.1, -0.1 - 2 * math.pi])
    wrapped = rb.wrap_angle(angles)
    np.testing.assert_allclose(wrapped, [math.pi, math.pi, math.pi, 0.1, -0.1], atol=1e-12)


def test_relative_pose_hand_computed():
    origin = np.array([1.0, 2.0, math.pi / 2])  # facing +y
    pose = np.array([1.0, 3.0, math.pi])  # 1 m ahead, turned left by 90 deg
    np.testing.assert_allclose(rb.relative_pose(pose, origin), [1.0, 0.0, math.pi / 2], atol=1e-12)
    pose = np.array([0.0, 2.0, -math.pi / 2 + 0.2])  # 1 m to the left of the start
    rel = rb.relative_pose(pose, origin)
    np.testing.assert_allclose(rel[:2], [0.0, 1.0], atol=1e-12)
    assert rel[2] == pytest.approx(rb.wrap_angle(-math.pi + 0.2))


def test_linearize_depth_inverts_projection():
    znear, zfar = 0.05, 50.0
    z = np.array([[0.1, 1.0], [2.0, 9.5]])
    # Reversed-Z window depth of a perspective projection: b = n (f - z) / (z (f - n)).
    buffer = (znear * (zfar - z) / (z * (zfar - znear))).astype(np.float32)
    np.testing.assert_allclose(linearize_depth(buffer, znear, zfar), z, rtol=1e-4)


# ----------------------------------------------------------------------------- rendering


def test_geom_instance_ids_from_names(world):
    model = world[0]
    ids = geom_instance_ids(model)
    seat = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "obj7_seat")
    assert ids[seat] == 7 and ids.sum() == 7


@pytest.mark.parametrize("distance", [0.6, 1.5, 2.75])
def test_depth_centre_pixel_reads_wall_distance(world, distance):
    model, data, handles, renderer = world
    rb.set_robot_pose(model, data, handles, np.array([WALL_X - distance, 0.4, 0.0]))
    rgb, depth = renderer.render(data)
    assert rgb.shape == (64, 64, 3) and rgb.dtype == np.uint8
    assert depth.shape == (64, 64) and depth.dtype == np.float32
    centre = depth[31:33, 31:33]  # the 4 pixels around the optical axis
    np.testing.assert_allclose(centre, distance, atol=0.02)
    # Planar z-depth: a flat wall reads the same distance across a whole row.
    np.testing.assert_allclose(depth[20, 8:56], distance, atol=0.02)


def test_depth_is_clipped_to_max_depth(world):
    model, data, handles, renderer = world
    # Looking south out of the open room: background beyond 10 m is clipped.
    rb.set_robot_pose(model, data, handles, np.array([0.0, 0.0, -math.pi / 2]))
    _, depth = renderer.render(data)
    assert depth.max() <= 10.0 and depth.min() >= 0.0
    assert np.isclose(depth[10], 10.0).any()  # sky above the horizon: nothing hit


def test_segmentation_sees_goal_only_when_facing_it(world):
    model, data, handles, renderer = world
    rb.set_robot_pose(model, data, handles, np.array([0.0, 0.0, math.pi]))  # faces the box
    rgb, _ = renderer.render(data)
    seg = renderer.render_segmentation(data)
    assert seg.dtype == np.int32 and seg.shape == (64, 64)
    assert set(np.unique(seg)) == {0, 7}
    # Where segmentation says "object 7", the colour image shows the red box.
    red = (rgb[..., 0].astype(int) - rgb[..., 1]) > 60
    assert (red[seg == 7]).mean() > 0.9
    rb.set_robot_pose(model, data, handles, np.array([0.0, 0.0, 0.0]))  # faces the wall
    renderer.render(data)
    assert set(np.unique(renderer.render_segmentation(data))) == {0}


# ----------------------------------------------------------------------------- kinematics


def test_free_driving_tracks_commands(world):
    model, data, handles, _ = world
    rb.set_robot_pose(model, data, handles, np.array([0.0, 0.0, math.pi / 4]))
    for _ in range(10):  # 1 s at 0.3 m/s along 45 degrees
        touched = rb.drive(model, data, handles, 0.3, 0.0, 5)
        assert not touched
    x, y, yaw = data.qpos[handles.qpos_adr]
    dist = math.hypot(x, y)
    assert dist == pytest.approx(0.3, abs=0.01)
    assert math.atan2(y, x) == pytest.approx(math.pi / 4, abs=1e-6) and yaw == pytest.approx(
        math.pi / 4, abs=1e-9
    )
    rb.set_robot_pose(model, data, handles, np.zeros(3))
    for _ in range(10):
        rb.drive(model, data, handles, 0.0, 1.0, 5)
    assert data.qpos[handles.qpos_adr[2]] == pytest.approx(1.0, abs=0.02)


def test_wall_stops_the_base(world):
    model, data, handles, _ = world
    rb.set_robot_pose(model, data, handles, np.array([2.0, 0.0, 0.0]))
    touched = [rb.drive(model, data, handles, 0.5, 0.0, 5) for _ in range(40)]
    x = data.qpos[handles.qpos_adr[0]]
    assert any(touched)
    assert x <= WALL_X - rb.ROBOT_RADIUS + 0.01  # at most 1 cm of contact penetration
    assert x >= WALL_X - rb.ROBOT_RADIUS - 0.02
