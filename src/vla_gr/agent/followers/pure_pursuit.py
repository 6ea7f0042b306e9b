"""Pure-pursuit follower: the latest S2 waypoints -> an action (v, w, stop) at every control step.

The follower sees only what the agent sees: the waypoints of the last plan (robot frame at
the tick), the pose (odometry) since then, and the current depth image. Between planner
ticks the waypoints are carried into the current robot frame by the odometry, so S2 can
run every few control steps while S1 keeps driving.

Action convention (the env's): ``(v, w, stop)`` in [-1, 1], fractions of the maximum linear
and angular speeds; ``stop > 0`` is the STOP decision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vla_gr.geometry.camera import intrinsics_from_hfov
from vla_gr.geometry.pose2d import lookahead_target, map_to_robot, robot_to_map
from vla_gr.geometry.robot_spec import (
    CAMERA_HEIGHT,
    HFOV_DEG,
    MAX_ANGULAR_SPEED,
    MAX_LINEAR_SPEED,
    MIN_DEPTH,
    ROBOT_RADIUS,
)


@dataclass
class PursuitConfig:
    """Speeds (from the robot spec), pursuit geometry and the depth safety check."""

    max_linear_speed: float = MAX_LINEAR_SPEED  # m/s at v = 1
    max_angular_speed: float = MAX_ANGULAR_SPEED  # rad/s at w = 1
    lookahead: float = 0.6  # m: the pursued point's distance along the waypoints
    arrive_distance: float = 0.15  # m: the last waypoint closer than this is reached
    turn_in_place: float = math.radians(50.0)  # |heading error| above this: turn in place
    # with an obstacle within slow_distance straight ahead, turn in place above this error
    # instead of arcing into it
    turn_in_place_near: float = math.radians(15.0)
    heading_gain: float = 2.5  # turn-in-place rate per radian of heading error
    min_turn: float = 0.3  # turn-in-place fraction floor, so a small error still closes
    max_linear: float = 1.0  # cap of the linear fraction
    # depth safety: the corridor ahead (robot width + margin) must be clear of points in the
    # obstacle height band; speed falls linearly from slow_distance to stop_distance
    robot_radius: float = ROBOT_RADIUS
    side_margin: float = 0.05
    stop_distance: float = 0.25  # m from the robot centre to the nearest point ahead
    slow_distance: float = 0.8
    floor_height: float = 0.1
    robot_height: float = 1.2
    camera_height: float = CAMERA_HEIGHT
    hfov_deg: float = HFOV_DEG
    min_depth: float = MIN_DEPTH
    # on a precise plan (the navigator's fine local path through a narrow gap): pursue this
    # near along it, and check a corridor of the robot's width plus this margin
    precise_lookahead: float = 0.3
    precise_side_margin: float = 0.0

    def __post_init__(self) -> None:
        for key in (
            "max_linear_speed", "max_angular_speed", "lookahead", "arrive_distance",
            "heading_gain", "slow_distance", "hfov_deg", "camera_height", "precise_lookahead",
        ):  # fmt: skip
            if not getattr(self, key) > 0:
                raise ValueError(f"model.pursuit.{key}={getattr(self, key)} must be > 0")
        if not 0.0 < self.turn_in_place_near <= self.turn_in_place:
            raise ValueError("model.pursuit.turn_in_place_near must be in (0, turn_in_place]")
        if not 0.0 < self.turn_in_place <= math.pi:
            raise ValueError(f"model.pursuit.turn_in_place={self.turn_in_place} must be in (0, pi]")
        if not 0.0 <= self.min_turn <= 1.0 or not 0.0 < self.max_linear <= 1.0:
            raise ValueError("model.pursuit.min_turn must be in [0, 1] and max_linear in (0, 1]")
        if not 0.0 <= self.stop_distance < self.slow_distance:
            raise ValueError(
                f"model.pursuit.stop_distance={self.stop_distance} must be in [0, slow_distance)"
            )
        if not (self.side_margin >= 0 and self.precise_side_margin >= 0):
            raise ValueError("model.pursuit.side_margin and precise_side_margin must be >= 0")
        if not self.floor_height < self.robot_height:
            raise ValueError("model.pursuit.floor_height must be < robot_height")


def clearance_ahead(depth: np.ndarray, cfg: PursuitConfig, bearing: float = 0.0) -> float:
    """Distance (m) from the robot centre to the nearest obstacle point in its corridor.

    The corridor (robot width + ``side_margin``) runs from the robot along ``bearing``
    (radians, counter-clockwise from the heading).

    Args:
        depth: (H, W) or (H, W, 1) planar depth in metres.

    Returns:
        inf when the visible part of the corridor is clear.
    """
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim == 3:
        d = d[..., 0]
    H, W = d.shape
    K = intrinsics_from_hfov(W, H, cfg.hfov_deg)
    left = -((np.arange(W) + 0.5 - K.cx) / K.fx)[None, :] * d  # (H, W)
    up = cfg.camera_height - ((np.arange(H) + 0.5 - K.cy) / K.fy)[:, None] * d  # (H, W) height
    ok = np.isfinite(d) & (d > cfg.min_depth)
    band = ok & (up >= cfg.floor_height) & (up <= cfg.robot_height)
    c, s = math.cos(bearing), math.sin(bearing)
    along = c * d + s * left  # (H, W) distance along the corridor
    across = -s * d + c * left  # (H, W)
    corridor = band & (along > 0) & (np.abs(across) <= cfg.robot_radius + cfg.side_margin)
    return float(along[corridor].min()) if corridor.any() else math.inf


def guarded_speed(v: float, clearance: float, cfg: PursuitConfig) -> float:
    """Forward fraction ``v`` scaled by the depth check: unchanged with ``clearance`` (m, the
    nearest obstacle in the corridor ahead) beyond ``slow_distance``, falling linearly to 0 at
    ``stop_distance``; backing up (``v <= 0``) is never limited."""
    if v <= 0:
        return v
    span = cfg.slow_distance - cfg.stop_distance
    return v * min(1.0, max(0.0, (clearance - cfg.stop_distance) / span))


def pursuit_action(
    target: np.ndarray, cfg: PursuitConfig, clearance: float = math.inf, ahead=math.inf
):
    """(v, w) fractions in [-1, 1] driving towards ``target`` (2,) in the robot frame.

    Heading errors above ``turn_in_place`` (``turn_in_place_near`` when an obstacle is within
    ``slow_distance`` straight ahead, ``ahead`` m) turn in place; otherwise the pure-pursuit
    arc (curvature 2 sin(alpha) / L) at a speed that falls with the heading error, is capped
    so the arc's turn rate fits ``max_angular_speed`` and falls to 0 as ``clearance`` (m, the
    nearest obstacle in the corridor towards the target) drops to ``stop_distance``.
    """
    dist = float(np.hypot(target[0], target[1]))
    if dist < 1e-6:
        return 0.0, 0.0
    alpha = math.atan2(target[1], target[0])
    limit = cfg.turn_in_place_near if ahead < cfg.slow_distance else cfg.turn_in_place
    clearance = min(clearance, ahead)
    if abs(alpha) > limit:
        rate = max(cfg.min_turn, min(1.0, cfg.heading_gain * abs(alpha)))
        return 0.0, math.copysign(rate, alpha)
    v = cfg.max_linear_speed * cfg.max_linear * math.cos(alpha) ** 2  # m/s
    span = cfg.slow_distance - cfg.stop_distance
    v *= min(1.0, max(0.0, (clearance - cfg.stop_distance) / span))
    curvature = 2.0 * math.sin(alpha) / dist  # 1/m
    if abs(curvature) * v > cfg.max_angular_speed:
        v = cfg.max_angular_speed / abs(curvature)
    w = curvature * v  # rad/s
    if v < 1e-3:  # blocked ahead: still turn towards the target
        w = math.copysign(max(cfg.min_turn, min(1.0, cfg.heading_gain * abs(alpha))), alpha)
        return 0.0, float(w)
    return float(v / cfg.max_linear_speed), float(np.clip(w / cfg.max_angular_speed, -1, 1))


class PurePursuit:
    """Follows the latest plan of :class:`~vla_gr.core.gr_field.Navigator` every control step.

    Usage: ``set_plan(plan, pose)`` after each planner tick, ``act(depth, pose)`` every step.
    """

    def __init__(self, config: PursuitConfig | None = None) -> None:
        self.config = config or PursuitConfig()
        self._precise_config = replace(
            self.config,
            lookahead=self.config.precise_lookahead,
            side_margin=self.config.precise_side_margin,
        )
        self.reset()

    def reset(self) -> None:
        """Forget the plan (the next ``act`` without a plan stands still)."""
        self._world: np.ndarray | None = None  # (K, 2) waypoints in the map frame
        self._command: tuple[float, float] | None = None
        self._stop = False
        self._max_speed = 1.0
        self._precise = False
        self.last_clearance = math.inf

    def set_plan(self, plan, pose) -> None:
        """Take a new plan made at ``pose`` (3,); its waypoints (K, 2) are in that robot frame."""
        pose = np.asarray(pose, dtype=np.float64)
        self._stop = bool(plan.stop)
        self._max_speed = float(getattr(plan, "max_speed", 1.0))
        self._precise = bool(getattr(plan, "precise", False))
        self._command = None if plan.command is None else tuple(plan.command)
        wps = np.asarray(plan.waypoints, dtype=np.float64).reshape(-1, 2)  # (K, 2)
        self._world = robot_to_map(wps, pose) if len(wps) else None  # (K, 2)

    def act(self, depth, pose, rgb=None) -> np.ndarray:
        """Action (3,) float32 = (v, w, stop) in [-1, 1] for depth (H, W[, 1]) and pose (3,).

        ``rgb`` is accepted for the follower protocol and not read."""
        cfg = self._precise_config if self._precise else self.config
        pose = np.asarray(pose, dtype=np.float64)
        if self._stop:
            return np.array([0.0, 0.0, 1.0], np.float32)
        self.last_clearance = clearance_ahead(depth, cfg)
        if self._command is not None:
            v, w = self._command
            v = guarded_speed(v, self.last_clearance, cfg)  # open-loop motion is checked too
            return np.array([np.clip(v, -1, 1), np.clip(w, -1, 1), -1.0], np.float32)
        if self._world is None:
            return np.array([0.0, 0.0, -1.0], np.float32)
        ego = map_to_robot(self._world, pose)  # (K, 2)
        if np.hypot(*ego[-1]) < cfg.arrive_distance:
            return np.array([0.0, 0.0, -1.0], np.float32)
        target = lookahead_target(ego, cfg.lookahead)  # (2,)
        bearing = math.atan2(target[1], target[0])
        towards = clearance_ahead(depth, cfg, bearing) if abs(bearing) > 1e-3 else math.inf
        v, w = pursuit_action(target, cfg, towards, self.last_clearance)
        if v > self._max_speed:  # slower on the same arc
            v, w = self._max_speed, w * self._max_speed / v
        return np.array([np.clip(v, -1, 1), np.clip(w, -1, 1), -1.0], np.float32)
