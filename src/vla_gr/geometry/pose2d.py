"""Planar poses and paths in numpy: angle wrapping, robot <-> map frames, pursuit points.

A pose is ``(x, y, yaw)`` in the map frame; the robot frame is (forward, left). The batched
torch versions for the GR field's tensors are :func:`vla_gr.geometry.camera.ego_to_world`
and :func:`~vla_gr.geometry.camera.world_to_ego`. Used by the world (odometry, the expert)
and by the agent (the navigator and the pure-pursuit follower).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["lookahead_target", "map_to_robot", "robot_to_map", "wrap_angle"]


def wrap_angle(angle):
    """Wrap radians to (-pi, pi] (scalar or array)."""
    wrapped = np.pi - np.mod(np.pi - np.asarray(angle, dtype=np.float64), 2.0 * np.pi)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def robot_to_map(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Robot-frame points (N, 2) (forward, left) at ``pose`` (3,) -> map-frame (N, 2)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    x = pose[0] + c * points[:, 0] - s * points[:, 1]  # (N,)
    y = pose[1] + s * points[:, 0] + c * points[:, 1]  # (N,)
    return np.stack([x, y], axis=-1)


def map_to_robot(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Map-frame points (N, 2) -> robot frame (N, 2) at ``pose`` (3,)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = points[:, 0] - pose[0], points[:, 1] - pose[1]  # (N,)
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def lookahead_target(waypoints: np.ndarray, lookahead: float) -> np.ndarray:
    """Point (2,) at arc length ``lookahead`` along the polyline robot -> ``waypoints`` (K, 2).

    Robot frame (the robot at the origin). The polyline starts at its point nearest to the
    robot (waypoints already passed are skipped); the last waypoint when it is shorter.
    """
    pts = np.concatenate([np.zeros((1, 2)), waypoints])  # (K + 1, 2) robot frame
    seg = pts[1:] - pts[:-1]  # (K, 2)
    length = np.maximum((seg**2).sum(-1), 1e-12)  # (K,)
    t = np.clip(-(pts[:-1] * seg).sum(-1) / length, 0.0, 1.0)  # (K,) projection of the robot
    foot = pts[:-1] + t[:, None] * seg  # (K, 2)
    d2 = (foot**2).sum(-1)  # (K,)
    k = int(np.nonzero(d2 <= d2.min() + 1e-9)[0][-1])  # ties: the latest segment
    path = np.concatenate([foot[k : k + 1], pts[k + 1 :]])  # (M, 2) from the nearest point
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    s = min(lookahead, float(arc[-1]))
    return np.array([np.interp(s, arc, path[:, 0]), np.interp(s, arc, path[:, 1])])
