"""The ObjectNav robot: a round base with a forward camera, driven by (v, w) commands.

The base is a cylinder (radius ``ROBOT_RADIUS`` = 0.18 m, like Habitat's ObjectNav agent)
on two world slide joints (x, y) and a yaw hinge, so ``qpos[:3]`` of the robot is exactly
its world pose (x, y, yaw). Velocity actuators track world-frame velocities computed from
the body-frame command each physics substep; MuJoCo contacts stop it at walls and
furniture. Contacts are frictionless (``condim=1`` with priority), so the base slides
along a wall instead of sticking to it, as Habitat's sliding agent does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from vla_gr.geometry.robot_spec import CAMERA_HEIGHT, HFOV_DEG, ROBOT_RADIUS

BASE_HEIGHT = 1.0  # collision cylinder reaches above the camera, so table tops stop it
BASE_CLEARANCE = 0.02  # gap under the cylinder: no floor contact, no floor friction
ROBOT_GROUP = 3  # geom group hidden from the robot's own camera
ROBOT_BODY = "robot"
ROBOT_CAMERA = "robot_camera"
ROBOT_GEOM = "robot_base"
JOINTS = ("robot_x", "robot_y", "robot_yaw")
TRACKING_TIME_CONSTANT = 0.005  # s: velocity actuators reach the command within ~1 substep


def vertical_fov_deg(hfov_deg: float, width: int, height: int) -> float:
    """MuJoCo's vertical fovy (degrees) for horizontal FOV ``hfov_deg`` on a W x H image."""
    if not 0.0 < hfov_deg < 180.0:
        raise ValueError(f"hfov_deg={hfov_deg} must be in (0, 180)")
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got width={width}, height={height}")
    half = math.radians(hfov_deg) / 2.0
    return math.degrees(2.0 * math.atan(math.tan(half) * height / width))


def wrap_angle(angle):
    """Wrap radians to (-pi, pi] (scalar or array)."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=np.float64), 2.0 * np.pi)


def relative_pose(pose_world: np.ndarray, origin_world: np.ndarray) -> np.ndarray:
    """Pose (3,) world (x, y, yaw) expressed in the frame of ``origin_world`` (3,).

    x is forward along the origin's heading, y to its left, yaw relative and wrapped to
    (-pi, pi] (Habitat's GPS + compass measured from the episode start).
    """
    dx = pose_world[0] - origin_world[0]
    dy = pose_world[1] - origin_world[1]
    c, s = math.cos(origin_world[2]), math.sin(origin_world[2])
    return np.array(
        [c * dx + s * dy, -s * dx + c * dy, float(wrap_angle(pose_world[2] - origin_world[2]))]
    )


def robot_body_xml(image_width: int = 64, image_height: int = 64) -> str:
    """MJCF ``<body>`` of the robot (placed at the world origin; joints carry the pose)."""
    fovy = vertical_fov_deg(HFOV_DEG, image_width, image_height)
    half = BASE_HEIGHT / 2.0
    return f"""
    <body name="{ROBOT_BODY}" pos="0 0 0">
      <joint name="{JOINTS[0]}" type="slide" axis="1 0 0" damping="0" armature="0"/>
      <joint name="{JOINTS[1]}" type="slide" axis="0 1 0" damping="0" armature="0"/>
      <joint name="{JOINTS[2]}" type="hinge" axis="0 0 1" damping="0" armature="0"/>
      <geom name="{ROBOT_GEOM}" type="cylinder" size="{ROBOT_RADIUS} {half}"
            pos="0 0 {BASE_CLEARANCE + half}" mass="20" group="{ROBOT_GROUP}"
            condim="1" priority="1" rgba="0.3 0.3 0.35 1"/>
      <camera name="{ROBOT_CAMERA}" pos="0 0 {CAMERA_HEIGHT}" xyaxes="0 -1 0 0 0 1"
              fovy="{fovy:.6f}"/>
    </body>"""


def add_robot_actuators(spec: mujoco.MjSpec) -> None:
    """Add one velocity actuator per robot joint to a parsed scene ``spec`` (in place)."""
    for joint in JOINTS:
        act = spec.add_actuator()
        act.name = f"{joint}_vel"
        act.target = joint
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_velocity(kv=1.0)  # gains are set from the compiled inertia below


@dataclass
class RobotHandles:
    """Indices of the robot inside a compiled model, and its control gains."""

    qpos_adr: np.ndarray  # (3,) qpos addresses of x, y, yaw
    qvel_adr: np.ndarray  # (3,) dof addresses
    actuator_ids: np.ndarray  # (3,)
    geom_id: int
    camera_id: int
    body_id: int


def configure_robot(model: mujoco.MjModel, control_hz: float, substeps: int) -> RobotHandles:
    """Set timestep, integrator and actuator gains on a compiled ``model``; return handles."""
    if control_hz <= 0:
        raise ValueError(f"control_hz={control_hz} must be > 0")
    if substeps < 1:
        raise ValueError(f"substeps={substeps} must be >= 1")
    model.opt.timestep = 1.0 / (control_hz * substeps)
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    model.opt.gravity[:] = 0.0  # planar robot, static furniture: gravity does nothing useful
    joint_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in JOINTS]
    if min(joint_ids) < 0:
        raise ValueError("model has no robot joints; build it with robot_body_xml()")
    act_ids = np.array(
        [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{j}_vel") for j in JOINTS]
    )
    body_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, ROBOT_BODY)
    dof_adr = model.jnt_dofadr[joint_ids]
    # Diagonal of the joint-space inertia (mass, mass, I_zz) sets gains for the same lag.
    for act, gain_mass in zip(act_ids, model.dof_M0[dof_adr]):
        kv = gain_mass / TRACKING_TIME_CONSTANT
        model.actuator_gainprm[act, 0] = kv
        model.actuator_biasprm[act, 2] = -kv
        model.actuator_ctrllimited[act] = 0
        # No force limit: a clamped force loses the implicit damping and oscillates; the
        # force is bounded anyway by kv times the velocity error.
        model.actuator_forcelimited[act] = 0
    return RobotHandles(
        qpos_adr=model.jnt_qposadr[joint_ids].copy(),
        qvel_adr=model.jnt_dofadr[joint_ids].copy(),
        actuator_ids=act_ids,
        geom_id=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, ROBOT_GEOM),
        camera_id=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, ROBOT_CAMERA),
        body_id=body_id,
    )


def set_robot_pose(
    model: mujoco.MjModel, data: mujoco.MjData, handles: RobotHandles, pose: np.ndarray
) -> None:
    """Reset ``data`` and place the robot at world ``pose`` (3,) = (x, y, yaw), at rest."""
    mujoco.mj_resetData(model, data)
    data.qpos[handles.qpos_adr] = pose
    mujoco.mj_forward(model, data)


def drive(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    handles: RobotHandles,
    linear: float,
    angular: float,
    substeps: int,
) -> bool:
    """Advance one control period with body-frame command ``linear`` m/s, ``angular`` rad/s.

    Returns whether the robot touched anything during the period.
    """
    qpos, ctrl = data.qpos, data.ctrl
    ax, ay, aw = handles.actuator_ids
    yaw_adr = handles.qpos_adr[2]
    touched = False
    for _ in range(substeps):
        yaw = qpos[yaw_adr]
        ctrl[ax] = linear * math.cos(yaw)
        ctrl[ay] = linear * math.sin(yaw)
        ctrl[aw] = angular
        mujoco.mj_step(model, data)
        # Only the robot moves and static-static pairs are never tested: any contact is its.
        touched = touched or data.ncon > 0
    return touched
