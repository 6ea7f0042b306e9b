"""The one robot and sensor spec: what the world simulates and what the agent assumes.

The MuJoCo robot (:mod:`vla_gr.envs.robot`), the environment's action scaling
(:mod:`vla_gr.envs.nav_env`), the geodesic expert and the ground-truth free space
(:mod:`vla_gr.envs.geodesic`), the GR field's mapping (:mod:`vla_gr.core.gr_field.config`)
and the configs' defaults all read these values; change them here only. Next in the data
flow: :mod:`vla_gr.geometry.camera` (depth -> points with this camera).
"""

from __future__ import annotations

__all__ = [
    "CAMERA_HEIGHT",
    "HFOV_DEG",
    "MAX_ANGULAR_SPEED",
    "MAX_DEPTH",
    "MAX_LINEAR_SPEED",
    "MIN_DEPTH",
    "ROBOT_RADIUS",
]

ROBOT_RADIUS = 0.18  # m, base cylinder (Habitat's ObjectNav agent)
CAMERA_HEIGHT = 0.88  # m above the floor, looking horizontally forward
HFOV_DEG = 79.0  # horizontal field of view of the RGB-D camera
MIN_DEPTH = 0.05  # m, nearer readings are treated as invalid by the mapping
MAX_DEPTH = 10.0  # m, depth is clipped here; a reading at MAX_DEPTH is a no-return
MAX_LINEAR_SPEED = 0.5  # m/s at action[0] = 1
MAX_ANGULAR_SPEED = 1.0  # rad/s at action[1] = 1
