"""Privileged geodesic expert for ObjectNav, with DART-style noise injection.

The expert reads ground truth from ``env.unwrapped`` (house, goal, distance fields, robot
pose), plans on a clearance-penalised cost field (so it keeps away from walls and corners),
extracts the path by steepest descent, follows it with pure pursuit on a lookahead point that
stays in line of sight, and near the goal turns to face the object before calling STOP.

With noise, :meth:`GeodesicExpert.act` returns a perturbed action to EXECUTE (Gaussian on
v/w plus occasional short random excursions) while :attr:`GeodesicExpert.last_label` holds the
noise-free expert action for the same observation, the pair a DART dataset stores.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from vla_gr.envs.geodesic import sample_field
from vla_gr.geometry import GridSpec, geodesic_distance
from vla_gr.geometry.pose2d import wrap_angle
from vla_gr.geometry.robot_spec import ROBOT_RADIUS

logger = logging.getLogger(__name__)

__all__ = [
    "ExpertConfig",
    "GeodesicExpert",
    "wrap_angle",
    "clearance_cost",
    "descend_path",
    "lookahead_point",
    "segment_clearance",
    "pursuit_command",
    "clearance_map",
    "planning_maps",
    "path_target",
    "field_reaches",
    "command_action",
]

# 8-neighbour offsets (d_row, d_col) and their lengths in cells.
_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])
_STEP_LEN = np.linalg.norm(_NEIGHBOURS, axis=1)  # (8,)


# ----------------------------------------------------------------------------- pure pieces


def clearance_cost(
    occupancy: np.ndarray,
    cell_size: float,
    robot_radius: float = ROBOT_RADIUS,
    margin: float = 0.3,
    weight: float = 6.0,
    contact_cost: float = 500.0,
) -> np.ndarray:
    """Cost per metre (H, W) that penalises cells near obstacles.

    ``clearance`` = distance from a cell to the nearest occupied cell minus ``robot_radius``.
    Cost is ``1 + weight * (1 - clearance / margin)^2`` for 0 <= clearance < margin, 1 beyond,
    and ``contact_cost`` where the robot would overlap an obstacle (clearance < 0), so a
    descent that starts there still leads out. Occupied cells get ``inf``-like cost via the
    caller's obstacle mask.

    Args:
        occupancy: (H, W) bool, True where an obstacle is.
    Returns:
        cost (H, W) float64 >= 1.
    """
    if cell_size <= 0 or margin <= 0:
        raise ValueError(f"cell_size and margin must be > 0, got {cell_size}, {margin}")
    occupancy = np.asarray(occupancy, dtype=bool)
    if not occupancy.any():
        return np.ones(occupancy.shape)
    clearance = clearance_map(occupancy, cell_size, robot_radius)  # (H, W)
    near = np.clip(1.0 - clearance / margin, 0.0, 1.0)  # (H, W)
    cost = 1.0 + weight * near**2  # (H, W)
    return np.where(clearance < 0.0, contact_cost, cost)


def clearance_map(
    occupancy: np.ndarray, cell_size: float, robot_radius: float = ROBOT_RADIUS
) -> np.ndarray:
    """Free space (H, W) in metres around a robot of ``robot_radius`` centred in each cell.

    Negative where the robot would overlap an occupied cell of ``occupancy`` (H, W) bool;
    ``inf`` everywhere when nothing is occupied.
    """
    occupancy = np.asarray(occupancy, dtype=bool)
    if not occupancy.any():
        return np.full(occupancy.shape, np.inf)
    return ndimage.distance_transform_edt(~occupancy) * cell_size - robot_radius  # (H, W)


def planning_maps(
    occupancy: np.ndarray,
    cell_size: float,
    robot_radius: float,
    margin: float,
    weight: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Cost per metre (H, W) and clearance in metres (H, W) on ``occupancy`` (H, W) bool.

    See :func:`clearance_cost` and :func:`clearance_map`, for a robot of ``robot_radius``.
    """
    cost = clearance_cost(occupancy, cell_size, robot_radius, margin, weight)  # (H, W)
    return cost, clearance_map(occupancy, cell_size, robot_radius)


def field_reaches(field: np.ndarray, rc: np.ndarray) -> bool:
    """Whether ``field`` (H, W) is finite in the 3 x 3 cells around cell ``rc`` (2,)."""
    r0, c0 = max(int(rc[0]) - 1, 0), max(int(rc[1]) - 1, 0)
    return bool(np.isfinite(field[r0 : int(rc[0]) + 2, c0 : int(rc[1]) + 2]).any())


def descend_path(
    field: np.ndarray, grid: GridSpec, start_xy: np.ndarray, max_length: float
) -> np.ndarray:
    """Steepest 8-neighbour descent of ``field`` (H, W) from ``start_xy`` (2,).

    Returns world points (N, 2): the start, then cell centres with strictly decreasing field
    values, until the field reaches 0 (a source), no neighbour is lower, or the path is
    ``max_length`` metres long.
    """
    rc = grid.world_to_cell(np.asarray(start_xy, dtype=np.float64))  # (2,)
    r = int(np.clip(rc[0], 0, grid.height - 1))
    c = int(np.clip(rc[1], 0, grid.width - 1))
    points = [np.asarray(start_xy, dtype=np.float64)[:2]]
    length = 0.0
    rows, cols = field.shape
    while length < max_length and field[r, c] > 0.0:
        rr = r + _NEIGHBOURS[:, 0]  # (8,)
        cc = c + _NEIGHBOURS[:, 1]  # (8,)
        ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        values = np.full(8, np.inf)
        values[ok] = field[rr[ok], cc[ok]]
        if np.isfinite(field[r, c]):
            # Prefer the steepest slope, not just the lowest value (diagonals are longer).
            k = int(np.argmin((values - field[r, c]) / _STEP_LEN))  # of (8,)
        else:  # started off the field (inside an obstacle cell): step to the lowest neighbour
            k = int(np.argmin(values))
        if not values[k] < field[r, c]:
            break
        r, c = int(rr[k]), int(cc[k])
        length += _STEP_LEN[k] * grid.cell_size
        points.append(grid.cell_to_world(np.array([r, c])))
    return np.stack(points)  # (N, 2)


def segment_clearance(clearance: np.ndarray, grid: GridSpec, a: np.ndarray, b: np.ndarray) -> float:
    """Smallest ``clearance`` (H, W) sampled every half cell along segment a (2,) -> b (2,).

    ``-inf`` if the segment leaves the grid.
    """
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / (0.5 * grid.cell_size))) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]  # (n, 1)
    rc = grid.world_to_cell(a[None] * (1 - t) + b[None] * t)  # (n, 2)
    if not grid.in_bounds(rc).all():
        return -math.inf
    return float(clearance[rc[:, 0], rc[:, 1]].min())


def lookahead_point(
    path: np.ndarray,
    lookahead: float,
    clearance: np.ndarray | None = None,
    grid: GridSpec | None = None,
    min_clearance: float = 0.0,
) -> np.ndarray:
    """Point (2,) on ``path`` (N, 2) at arc length ``lookahead`` from its start.

    With ``clearance`` (H, W) and ``grid``, the point is pulled back along the path until the
    straight segment from the start to it keeps ``min_clearance`` (line of sight). Where the
    start itself is closer to an obstacle than that, the segment only has to get no closer
    than the start (minus a cell), so the robot can still leave a tight spot.
    """
    if len(path) == 1:
        return path[0].copy()
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)  # (N-1,)
    arc = np.concatenate([[0.0], np.cumsum(seg)])  # (N,)
    k = int(np.searchsorted(arc, lookahead))
    k = min(max(k, 1), len(path) - 1)
    if clearance is not None and grid is not None:
        rc = grid.world_to_cell(path[0])  # (2,)
        here = float(clearance[rc[0], rc[1]]) if grid.in_bounds(rc) else -math.inf
        need = min(min_clearance, here - grid.cell_size)
        while k > 1 and segment_clearance(clearance, grid, path[0], path[k]) < need:
            k -= 1
    return path[k].copy()


def path_target(
    field: np.ndarray,
    grid: GridSpec,
    clearance: np.ndarray,
    start_xy: np.ndarray,
    lookahead: float,
    min_clearance: float,
    end_xy: np.ndarray | None = None,
) -> np.ndarray:
    """Pursuit point (2,): :func:`lookahead_point` on the descent of ``field`` (H, W).

    The path starts at ``start_xy`` (2,); when it reaches the field's source, ``end_xy`` (2,)
    (an exact destination inside the source cell) is appended to it.
    """
    path = descend_path(field, grid, start_xy, lookahead + 0.2)  # (N, 2)
    if end_xy is not None:
        rc = grid.world_to_cell(path[-1])  # (2,)
        if grid.in_bounds(rc) and field[rc[0], rc[1]] == 0.0:
            path = np.concatenate([path, np.asarray(end_xy, np.float64)[None, :2]])  # (N+1, 2)
    return lookahead_point(path, lookahead, clearance, grid, min_clearance)


def command_action(v: float, w: float, max_linear: float, max_angular: float) -> np.ndarray:
    """Env action (3,) float32 (v, w fractions in [-1, 1], stop = -1) for (v m/s, w rad/s)."""
    return np.array(
        [np.clip(v / max_linear, -1, 1), np.clip(w / max_angular, -1, 1), -1.0], dtype=np.float32
    )


def pursuit_command(
    pose: np.ndarray,
    target: np.ndarray,
    max_linear: float,
    max_angular: float,
    turn_in_place: float = math.radians(55.0),
    heading_gain: float = 2.5,
) -> tuple[float, float]:
    """Pure-pursuit (v m/s, w rad/s) driving ``pose`` (3,) = (x, y, yaw) to ``target`` (2,).

    Large heading errors turn in place; otherwise the robot follows the pure-pursuit arc
    (curvature 2 sin(alpha) / L) and slows down so the arc's turn rate stays within
    ``max_angular``, also slowing as the heading error grows.
    """
    dx, dy = float(target[0] - pose[0]), float(target[1] - pose[1])
    dist = math.hypot(dx, dy)
    alpha = wrap_angle(math.atan2(dy, dx) - float(pose[2]))
    if dist < 1e-6:
        return 0.0, 0.0
    if abs(alpha) > turn_in_place:
        return 0.0, math.copysign(max_angular, alpha) * min(1.0, heading_gain * abs(alpha))
    curvature = 2.0 * math.sin(alpha) / dist
    v = max_linear * max(0.0, math.cos(alpha)) ** 2
    if abs(curvature) * v > max_angular:
        v = max_angular / abs(curvature)
    w = float(np.clip(curvature * v, -max_angular, max_angular))
    return v, w


# ----------------------------------------------------------------------------- the expert


@dataclass(frozen=True)
class ExpertConfig:
    """Tuning knobs of the expert (metres, radians, steps)."""

    stop_distance: float = 0.75  # call STOP at this geodesic distance or closer
    face_tolerance: float = math.radians(12.0)  # heading error to the goal accepted at STOP
    lookahead: float = 0.6
    clearance_margin: float = 0.3
    clearance_weight: float = 6.0
    min_free_clearance: float = 0.04  # line-of-sight segments keep this much clearance
    # Obstacles are rasterised by cell centres, so real geometry can reach ~half a cell (a
    # diagonal) past the occupancy grid: plan for a robot this much larger than it is.
    radius_slack_cells: float = 0.75
    excursion_steps: tuple[int, int] = (3, 8)  # DART excursion length range (inclusive)
    # Blocked-motion recovery: after this many steps that moved < 25% of the command, mark
    # the spot ahead as an obstacle, back up and re-plan; give up (STOP) after max_replans
    # re-plans, 3 * max_replans blocked events, patience_steps / 2 steps held back by contact,
    # or patience_steps without progress.
    blocked_steps: int = 3
    backup_steps: int = 3
    blocked_obstacle_radius: float = 0.1
    max_replans: int = 6
    patience_steps: int = 80  # give up if the planned cost-to-go has not dropped for this long

    def __post_init__(self) -> None:
        for name in ("stop_distance", "lookahead", "clearance_margin", "face_tolerance"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ExpertConfig.{name} must be > 0, got {getattr(self, name)}")


class GeodesicExpert:
    """Follows the geodesic to the goal and stops facing it; optional DART-style noise.

    Args:
        env: a ``VLAGR/ObjectNav-v0`` env (possibly wrapped); ground truth is read from
            ``env.unwrapped``.
        noise_std: std of Gaussian noise added to the executed (v, w) fractions.
        noise_prob: per-step probability of starting a short random excursion.
        seed: seed of the noise generator.
    """

    def __init__(
        self,
        env,
        noise_std: float = 0.0,
        noise_prob: float = 0.0,
        seed: int | None = None,
        config: ExpertConfig | None = None,
    ) -> None:
        if noise_std < 0:
            raise ValueError(f"noise_std must be >= 0, got {noise_std}")
        if not 0.0 <= noise_prob <= 1.0:
            raise ValueError(f"noise_prob must be in [0, 1], got {noise_prob}")
        self.env = env
        self.noise_std = float(noise_std)
        self.noise_prob = float(noise_prob)
        self.config = config or ExpertConfig()
        self.rng = np.random.default_rng(seed)
        self.last_label = np.zeros(3, np.float32)
        self._plan_key = None
        self._field: np.ndarray | None = None
        self._excursion_left = 0
        self._excursion_action = np.zeros(3, np.float32)

    # -- planning ------------------------------------------------------------------------
    def reset(self) -> None:
        """Plan for the env's current episode; call after ``env.reset``."""
        u = self.env.unwrapped
        house, goal = u.house, u.goal
        self._excursion_left = 0
        self.last_label = np.zeros(3, np.float32)
        self._prev_pose: np.ndarray | None = None
        self._prev_command = (0.0, 0.0)  # executed (v, w) fractions; zeros for excursions
        self._face_steps = 0
        self._blocked = 0
        self._backup_left = 0
        self._backup_sign = -1.0
        self._strained = False
        self._strained_steps = 0
        self._replans = 0
        self._blocked_events = 0
        self._best_cost = math.inf
        self._since_progress = 0
        self.gave_up = False
        key = (id(house), house.seed, goal.instance_id)
        if key == self._plan_key:
            return
        self._grid: GridSpec = house.grid
        self._footprint = house.object_ids == goal.instance_id  # (H, W)
        if not self._footprint.any():
            raise ValueError(f"goal {goal.instance_id} has no footprint in house {house.seed}")
        walls = house.occupancy & ~self._footprint  # (H, W)
        # Fallback measure of the distance to the goal (unit cost) if the env's is unusable.
        self._unit_field = geodesic_distance(1.0, self._footprint, walls, self._grid.cell_size)
        self._plan(house.occupancy)
        self._plan_key = key
        logger.debug("planned for house %s goal %s", house.seed, goal.instance_id)

    def _plan(self, occupancy: np.ndarray) -> None:
        """Cost-aware distance field and clearance map (H, W) for ``occupancy`` (H, W)."""
        cfg, grid = self.config, self._grid
        radius = ROBOT_RADIUS + cfg.radius_slack_cells * grid.cell_size
        cost, self._clearance = planning_maps(
            occupancy, grid.cell_size, radius, cfg.clearance_margin, cfg.clearance_weight
        )  # (H, W) each
        walls = occupancy & ~self._footprint  # (H, W)
        self._field = geodesic_distance(cost, self._footprint, walls, grid.cell_size)  # (H, W)
        self._occupancy = occupancy

    def _mark_blocked(self, pose: np.ndarray) -> None:
        """Add an obstacle disk just ahead of ``pose`` (3,) and re-plan around it."""
        cfg, grid = self.config, self._grid
        reach = ROBOT_RADIUS + 0.5 * cfg.blocked_obstacle_radius
        ahead = pose[:2] + reach * np.array([math.cos(pose[2]), math.sin(pose[2])])  # (2,)
        xs, ys = grid.cell_centres()  # (H, W) each
        disk = (xs - ahead[0]) ** 2 + (ys - ahead[1]) ** 2 <= cfg.blocked_obstacle_radius**2
        new = disk & ~self._footprint & ~self._occupancy  # (H, W)
        if not new.any():  # pushed against a known obstacle (e.g. after noise): just back up
            return
        self._plan(self._occupancy | new)
        self._best_cost, self._since_progress = math.inf, 0  # costs changed with the map
        self._plan_key = None  # the next episode re-plans from the house's own map
        self._replans += 1
        logger.debug("blocked at %s: re-plan %d", np.round(pose, 2), self._replans)

    def distance_to_goal(self, xy: np.ndarray) -> float:
        """Geodesic distance (m) from ``xy`` (2,) to the goal footprint, as the env measures it."""
        field = getattr(self.env.unwrapped, "goal_distance", None)
        if field is not None:
            d = sample_field(field, self._grid, float(xy[0]), float(xy[1]))
            if math.isfinite(d):
                return d
        return sample_field(self._unit_field, self._grid, float(xy[0]), float(xy[1]))

    # -- control -------------------------------------------------------------------------
    def expert_action(self) -> np.ndarray:
        """Noise-free action (3,) float32 for the robot's current ground-truth pose."""
        if self._field is None:
            self.reset()
        u = self.env.unwrapped
        pose = np.asarray(u.robot_pose_world(), dtype=np.float64)  # (3,)
        vmax, wmax = float(u.max_linear_speed), float(u.max_angular_speed)
        cfg = self.config
        goal = u.goal
        if self.distance_to_goal(pose[:2]) <= cfg.stop_distance:
            err = wrap_angle(math.atan2(goal.y - pose[1], goal.x - pose[0]) - pose[2])
            self._face_steps += 1
            # Stop once facing the goal, or if turning is obstructed (already successful).
            if abs(err) <= cfg.face_tolerance or self._face_steps > cfg.patience_steps // 2:
                return np.array([0.0, 0.0, 1.0], np.float32)
            w = math.copysign(wmax * min(1.0, 2.0 * abs(err)), err)
            return command_action(0.0, w, vmax, wmax)
        blocked = self._is_blocked(pose, vmax / float(u.control_hz), wmax / float(u.control_hz))
        if blocked:
            self._blocked_events += 1
            if blocked == "forward":
                self._mark_blocked(pose)
            self._backup_left = cfg.backup_steps
            self._backup_sign = self._escape_sign(pose)
        rc = self._grid.world_to_cell(pose[:2])  # (2,)
        stuck = self._replans > cfg.max_replans or self._blocked_events > 3 * cfg.max_replans
        self._strained_steps += int(self._strained)
        stuck = stuck or self._no_progress(rc) or self._strained_steps > cfg.patience_steps // 2
        if self.gave_up or stuck or not self._reachable(rc):
            if not self.gave_up:
                logger.warning("expert gives up: the goal cannot be reached from %s", pose)
            self.gave_up = True
            return np.array([0.0, 0.0, 1.0], np.float32)
        if self._backup_left > 0:
            self._backup_left -= 1
            return command_action(0.5 * self._backup_sign * vmax, 0.0, vmax, wmax)
        target = path_target(
            self._field,
            self._grid,
            self._clearance,
            pose[:2],
            cfg.lookahead,
            cfg.min_free_clearance,
        )  # (2,)
        touching = self._strained and self._clearance[rc[0], rc[1]] < 0.0
        if touching:
            # Held back by an obstacle (e.g. pushed there by noise): aim away from it as well
            # as along the path, so the arc does not cut the corner it is touching.
            away = self._clearance_gradient(rc)  # (2,)
            along = (target - pose[:2]) / max(float(np.linalg.norm(target - pose[:2])), 1e-6)
            target = pose[:2] + 0.3 * (along + away)  # (2,)
        v, w = pursuit_command(pose, target, vmax, wmax)
        if v == 0.0 and touching:
            # Turning in place while touching something: ease away from it as well, since a
            # contact can stall the rotation.
            v = 0.3 * vmax * self._escape_sign(pose)
        return command_action(v, w, vmax, wmax)

    def _clearance_gradient(self, rc: np.ndarray) -> np.ndarray:
        """Unit direction (2,) as (x, y) of increasing clearance at cell ``rc`` (2,)."""
        r, c = int(rc[0]), int(rc[1])
        h, w = self._clearance.shape
        r0, r1, c0, c1 = max(r - 1, 0), min(r + 1, h - 1), max(c - 1, 0), min(c + 1, w - 1)
        gx = self._clearance[r, c1] - self._clearance[r, c0]
        gy = self._clearance[r1, c] - self._clearance[r0, c]
        norm = math.hypot(gx, gy)
        return np.array([gx, gy]) / norm if norm > 0 else np.zeros(2)

    def _no_progress(self, rc: np.ndarray) -> bool:
        """True once the planned cost-to-go at cell ``rc`` (2,) stalls for ``patience_steps``."""
        cost = float(self._field[rc[0], rc[1]]) if self._grid.in_bounds(rc) else math.inf
        if cost < self._best_cost - 0.05:
            self._best_cost, self._since_progress = cost, 0
        elif self._excursion_left == 0:  # noise excursions do not use up the patience
            self._since_progress += 1
        return self._since_progress > self.config.patience_steps

    def _reachable(self, rc: np.ndarray) -> bool:
        return field_reaches(self._field, rc)

    def _is_blocked(self, pose: np.ndarray, full_step: float, full_turn: float) -> str | None:
        """'forward' / 'turn' after ``blocked_steps`` steps whose command moved (turned) the
        robot < 25% of what it asked for (``full_step`` m, ``full_turn`` rad at full command).

        Also sets ``_strained`` when this step's progress fell below 60% of the command.
        """
        prev, (v, w) = self._prev_pose, self._prev_command
        self._strained, kind = False, None
        if prev is None:
            return None
        heading = np.array([math.cos(prev[2]), math.sin(prev[2])])  # (2,)
        forward = float(np.dot(pose[:2] - prev[:2], heading))  # m, signed
        turned = wrap_angle(pose[2] - prev[2]) * math.copysign(1.0, w)  # rad, signed
        if v > 0.1:
            self._strained = forward < 0.6 * v * full_step
            kind = "forward" if forward < 0.25 * v * full_step else None
        if abs(w) > 0.3:
            self._strained = self._strained or turned < 0.6 * abs(w) * full_turn
            if abs(v) <= 0.1 and turned < 0.25 * abs(w) * full_turn:
                kind = "turn"
        self._blocked = self._blocked + 1 if kind else 0
        if self._blocked >= self.config.blocked_steps:
            self._blocked = 0
            return kind
        return None

    def _escape_sign(self, pose: np.ndarray) -> float:
        """+1 to drive forward, -1 backward: whichever side along the heading has more room."""
        heading = np.array([math.cos(pose[2]), math.sin(pose[2])])  # (2,)
        room = []
        for sign in (1.0, -1.0):
            rc = self._grid.world_to_cell(pose[:2] + sign * 0.15 * heading)  # (2,)
            inside = self._grid.in_bounds(rc)
            room.append(float(self._clearance[rc[0], rc[1]]) if inside else -math.inf)
        return 1.0 if room[0] > room[1] else -1.0

    def act(self, obs=None) -> np.ndarray:
        """Action (3,) float32 to execute; the noise-free label is kept in ``last_label``."""
        action = self._noisy(self.expert_action())  # (3,)
        self._prev_pose = np.asarray(self.env.unwrapped.robot_pose_world(), dtype=np.float64)
        # Blocked-motion checks only for commands the expert chose (not random excursions).
        free_choice = self._excursion_left == 0
        self._prev_command = (float(action[0]), float(action[1])) if free_choice else (0.0, 0.0)
        return action

    def _noisy(self, label: np.ndarray) -> np.ndarray:
        """The executed action (3,) for noise-free ``label`` (3,)."""
        self.last_label = label.copy()
        if label[2] > 0 or (self.noise_std == 0 and self.noise_prob == 0):
            self._excursion_left = 0
            return label
        if self._excursion_left == 0 and self.rng.random() < self.noise_prob:
            lo, hi = self.config.excursion_steps
            self._excursion_left = int(self.rng.integers(lo, hi + 1))
            self._excursion_action = np.array(
                [self.rng.uniform(0.0, 1.0), self.rng.uniform(-1.0, 1.0), -1.0], np.float32
            )
        if self._excursion_left > 0:
            self._excursion_left -= 1
            action = self._excursion_action.copy()
        else:
            action = label.copy()
        if self.noise_std > 0:
            action[:2] += self.rng.normal(0.0, self.noise_std, size=2).astype(np.float32)
        action[:2] = np.clip(action[:2], -1.0, 1.0)
        action[2] = -1.0
        return action
