"""What the learned S1 reads: the current RGB-D, pooled small, and the latest S2 plan as a vector.

:class:`PlanMemory` keeps the last :class:`~vla_gr.core.gr_field.NavPlan` in the odometry (map)
frame and re-expresses it in the current robot frame at every control step, so S1 sees where
S2 wants it to go even between planner ticks. The same code builds S1's inputs at inference
and when its training data is relabelled, so the two cannot drift apart.

Plan vector layout (``plan_vector_size(path_points)`` floats)::

    [ path points (x, y) / 2 m  at each arc length of path_points   2 * len(path_points)
      has path, distance to the last waypoint / 5 m (clipped)       2
      open-loop command (v, w), has command                         3
      STOP requested                                                1
      goal confidence, goal distance / 5 m (clipped), goal known    3
      speed cap                                                     1
      mode one-hot (navigator MODES)                                len(MODES)
      steps since the plan / 10 (clipped)                           1 ]
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vla_gr.agent.navigator.navigator import MODES
from vla_gr.geometry.pose2d import lookahead_target, map_to_robot, robot_to_map

__all__ = ["PlanMemory", "plan_vector_size", "pool_rgbd"]

_POSITION_SCALE = 2.0  # m
_DISTANCE_SCALE = 5.0  # m


def plan_vector_size(path_points: Sequence[float]) -> int:
    """Length of :meth:`PlanMemory.vector` for ``path_points`` arc lengths."""
    return 2 * len(path_points) + 2 + 3 + 1 + 3 + 1 + len(MODES) + 1


def pool_rgbd(rgb: np.ndarray, depth: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Average-pool an env frame to ``size`` x ``size``.

    Args:
        rgb: (H, W, 3) uint8; depth: (H, W) or (H, W, 1) metres; H and W divisible by size.

    Returns:
        rgb (3, size, size) uint8 and depth (1, size, size) float32 metres.
    """
    rgb = np.asarray(rgb)
    d = np.asarray(depth, dtype=np.float32)
    d = d[..., 0] if d.ndim == 3 else d  # (H, W)
    H, W = d.shape
    if rgb.shape[:2] != (H, W) or H % size or W % size:
        raise ValueError(f"rgb {rgb.shape} and depth {d.shape} must share H, W divisible by {size}")
    fh, fw = H // size, W // size
    img = rgb.astype(np.float32).reshape(size, fh, size, fw, 3).mean((1, 3))  # (s, s, 3)
    d = np.nan_to_num(d, nan=0.0, posinf=0.0).reshape(size, fh, size, fw).mean((1, 3))  # (s, s)
    return np.rint(img).astype(np.uint8).transpose(2, 0, 1), d[None].astype(np.float32)


class PlanMemory:
    """The latest S2 plan in the odometry frame; ``vector(pose, step)`` for S1.

    Args:
        path_points: arc lengths (m) at which the path is sampled for the vector.
    """

    def __init__(self, path_points: Sequence[float] = (0.25, 0.5, 1.0, 2.0)) -> None:
        self.path_points = tuple(float(p) for p in path_points)
        self.size = plan_vector_size(self.path_points)
        self.reset()

    def reset(self) -> None:
        """No plan: the vector is all zeros but the 'steps since' slot."""
        self.plan = None
        self.waypoints_world: np.ndarray | None = None  # (K, 2) odometry frame
        self.plan_step = 0

    def set_plan(self, plan, pose: np.ndarray, step: int) -> None:
        """Take ``plan`` (a NavPlan) made at ``pose`` (3,) on control step ``step``."""
        self.plan = plan
        wps = np.asarray(plan.waypoints, dtype=np.float64).reshape(-1, 2)  # (K, 2) robot frame
        pose = np.asarray(pose, dtype=np.float64)
        self.waypoints_world = robot_to_map(wps, pose) if len(wps) else None
        self.plan_step = int(step)

    def vector(self, pose: np.ndarray, step: int) -> np.ndarray:
        """The plan as seen from ``pose`` (3,) at control step ``step`` -> (P,) float32."""
        v = np.zeros(self.size, np.float32)
        n = 2 * len(self.path_points)
        plan = self.plan
        if self.waypoints_world is not None:
            ego = map_to_robot(self.waypoints_world, np.asarray(pose, np.float64))  # (K, 2)
            for i, s in enumerate(self.path_points):
                v[2 * i : 2 * i + 2] = lookahead_target(ego, s) / _POSITION_SCALE
            v[n] = 1.0
            v[n + 1] = min(float(np.hypot(*ego[-1])), _DISTANCE_SCALE) / _DISTANCE_SCALE
        i = n + 2
        if plan is not None:
            if plan.command is not None:
                v[i : i + 3] = (plan.command[0], plan.command[1], 1.0)
            v[i + 3] = float(plan.stop)
            v[i + 4] = float(plan.goal_confidence)
            if math.isfinite(plan.goal_distance):
                v[i + 5] = min(plan.goal_distance, _DISTANCE_SCALE) / _DISTANCE_SCALE
                v[i + 6] = 1.0
            v[i + 7] = float(plan.max_speed)
            v[i + 8 + MODES.index(plan.mode)] = 1.0
        v[-1] = min(step - self.plan_step, 10) / 10.0
        return v
