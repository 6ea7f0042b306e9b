"""Privileged *local* teacher: the labels the learned S1 controller imitates.

S1 only sees what S2 tells it (waypoints, an open-loop command, a STOP request) and the
robot's odometry, so its teacher must produce labels that are inferable from that:

- it drives to S2's last waypoint, never to the hidden goal, and it never goes looking for
  the goal itself;
- it uses the true map only to drive there without collisions (a cost-aware geodesic on
  the true occupancy, pursued like :class:`~vla_gr.envs.expert.GeodesicExpert` does), and to
  keep S2's open-loop commands from driving into obstacles;
- it calls STOP only when S2 asks for it and the robot is inside the success distance (with
  a margin) by the env's own measure; otherwise a STOP request means standing still.

Frames: ``pose`` and ``waypoints`` are in the agent's odometry frame (``obs["pose"]``, relative
to the episode start); the teacher maps them to the world with the start pose.

Cost: the field is re-planned only when the target moves by more than a cell; one re-plan is
a fast-marching pass over the whole house grid (at most ~250 x 250 cells), a few ms, so no
window around robot and target is needed.
"""

from __future__ import annotations

import logging
import math
import numbers
import time
from dataclasses import dataclass, fields

import numpy as np
from scipy import ndimage

from vla_gr.envs.expert import (
    command_action,
    field_reaches,
    path_target,
    planning_maps,
    pursuit_command,
)
from vla_gr.envs.geodesic import distance_at, goal_distance_field
from vla_gr.geometry import GridSpec, geodesic_distance
from vla_gr.geometry.pose2d import robot_to_map, wrap_angle
from vla_gr.geometry.robot_spec import ROBOT_RADIUS

logger = logging.getLogger(__name__)

__all__ = ["LocalTeacherConfig", "LocalTeacher"]

_IDLE = (0.0, 0.0, -1.0)
_STOP = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class LocalTeacherConfig:
    """Tuning knobs of the local teacher (metres, steps)."""

    stop_margin: float = 0.1  # STOP only this far inside the success distance
    arrive_distance: float = 0.15  # at the target within this: stand still
    lookahead: float = 0.6
    clearance_margin: float = 0.3
    clearance_weight: float = 6.0
    min_free_clearance: float = 0.04  # line-of-sight segments keep this much clearance
    # Obstacles are rasterised by cell centres: plan for a robot this much (cells) larger.
    radius_slack_cells: float = 0.75
    command_horizon_steps: int = 2  # open-loop commands are checked this many steps ahead

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise ValueError(
                    f"LocalTeacherConfig.{f.name} must be a finite number, got {value!r}"
                )
        for name in ("arrive_distance", "lookahead", "clearance_margin"):
            if not getattr(self, name) > 0:
                raise ValueError(
                    f"LocalTeacherConfig.{name} must be > 0, got {getattr(self, name)}"
                )
        for name in ("stop_margin", "clearance_weight", "min_free_clearance", "radius_slack_cells"):
            if getattr(self, name) < 0:
                raise ValueError(
                    f"LocalTeacherConfig.{name} must be >= 0, got {getattr(self, name)}"
                )
        if (
            int(self.command_horizon_steps) != self.command_horizon_steps
            or self.command_horizon_steps < 1
        ):
            raise ValueError(
                "LocalTeacherConfig.command_horizon_steps must be an integer >= 1, "
                f"got {self.command_horizon_steps}"
            )


def odometry_to_world(pose: np.ndarray, start_world: np.ndarray) -> np.ndarray:
    """World pose (3,) of odometry ``pose`` (3,) measured from world ``start_world`` (3,)."""
    xy = robot_to_map(np.asarray(pose, np.float64)[None, :2], start_world)[0]  # (2,)
    return np.array([xy[0], xy[1], wrap_angle(float(pose[2]) + float(start_world[2]))])


class LocalTeacher:
    """Follows S2's last waypoint collision-free on the true map; STOP only at the goal.

    Args:
        env: a ``VLAGR/ObjectNav-v0`` env (possibly wrapped); ground truth is read from
            ``env.unwrapped``. Call :meth:`reset` after each ``env.reset``.
        config: tuning knobs.

    ``replan_seconds`` holds the duration of every re-plan (geodesic field) since creation.
    """

    def __init__(self, env, config: LocalTeacherConfig | None = None) -> None:
        self.env = env
        self.config = config or LocalTeacherConfig()
        self.replan_seconds: list[float] = []
        self._map_key = None
        self._grid: GridSpec | None = None

    # -- ground truth --------------------------------------------------------------------
    def reset(self) -> None:
        """Read the env's current episode; call after ``env.reset``."""
        u = self.env.unwrapped
        cfg = self.config
        self._stop_within = float(u.success_distance) - cfg.stop_margin
        if not self._stop_within > 0:
            raise ValueError(
                f"LocalTeacherConfig.stop_margin={cfg.stop_margin} must be smaller than the "
                f"env's success_distance={u.success_distance}"
            )
        house = u.house
        self._start = np.asarray(u.start_pose_world, np.float64).copy()  # (3,)
        self._vmax, self._wmax = float(u.max_linear_speed), float(u.max_angular_speed)
        self._dt = 1.0 / float(u.control_hz)
        self._goal_field = getattr(u, "goal_distance", None)  # (H, W) the env's measure
        if self._goal_field is None:
            self._goal_field = goal_distance_field(house, u.goal.instance_id)
        self._target: np.ndarray | None = None  # world (2,) of the last plan
        self._dest: np.ndarray | None = None  # world (2,) where that plan leads
        self._field: np.ndarray | None = None  # (H, W) cost-to-go to _dest
        key = (id(house), house.seed)
        if key == self._map_key:
            return
        grid = house.grid
        radius = ROBOT_RADIUS + cfg.radius_slack_cells * grid.cell_size
        self._cost, self._clearance = planning_maps(
            house.occupancy, grid.cell_size, radius, cfg.clearance_margin, cfg.clearance_weight
        )  # (H, W) each
        free = self._clearance >= 0.0  # (H, W) where the robot fits
        if not free.any():
            raise ValueError(f"house {house.seed} has no cell where the robot fits")
        self._labels, _ = ndimage.label(free, structure=np.ones((3, 3), int))  # (H, W)
        self._nearest_free = ndimage.distance_transform_edt(
            ~free, return_distances=False, return_indices=True
        )  # (2, H, W) row, col of the nearest free cell
        self._nearest_in: dict[int, np.ndarray] = {}  # label -> (2, H, W), filled on demand
        self._occupancy = house.occupancy
        self._grid = grid
        self._map_key = key
        logger.debug(
            "local teacher: map of house %s (%d components)", house.seed, self._labels.max()
        )

    def to_world(self, pose: np.ndarray) -> np.ndarray:
        """World pose (3,) of odometry ``pose`` (3,) (the agent's ``obs["pose"]``)."""
        return odometry_to_world(pose, self._start)

    def goal_distance(self, pose: np.ndarray) -> float:
        """Distance (m) to the goal as the env judges success, at odometry ``pose`` (3,)."""
        world = self.to_world(pose)
        return distance_at(self._goal_field, self._grid, float(world[0]), float(world[1]))

    # -- control -------------------------------------------------------------------------
    def act(
        self,
        pose: np.ndarray,
        waypoints: np.ndarray,
        command=None,
        stop_requested: bool = False,
    ) -> np.ndarray:
        """Action (3,) float32 = (v, w, stop) in the env's convention.

        Args:
            pose: odometry pose (3,) (``obs["pose"]``).
            waypoints: S2's waypoints (K, 2) in the odometry frame; K may be 0.
            command: S2's open-loop (v, w) fractions, or None.
            stop_requested: whether S2 asks for STOP.
        """
        if self._grid is None:
            raise RuntimeError("LocalTeacher.act called before reset()")
        pose = np.asarray(pose, np.float64)
        if stop_requested:
            inside = self.goal_distance(pose) <= self._stop_within
            return np.array(_STOP if inside else _IDLE, np.float32)
        world = self.to_world(pose)  # (3,)
        if command is not None:
            return self._guarded(world, command)
        waypoints = np.asarray(waypoints, np.float64).reshape(-1, 2)  # (K, 2)
        if len(waypoints) == 0:
            return np.array(_IDLE, np.float32)
        target = robot_to_map(waypoints[-1:], self._start)[0]  # (2,) world
        return self._drive_to(world, target)

    def _guarded(self, world: np.ndarray, command) -> np.ndarray:
        """``command`` clipped; v zeroed if it drives into inflated obstacles soon."""
        v, w = np.clip(np.asarray(command, np.float64).reshape(-1)[:2], -1.0, 1.0)
        if v != 0.0 and self._enters_obstacle(world, v * self._vmax, w * self._wmax):
            v = 0.0
        return np.array([v, w, -1.0], np.float32)

    def _enters_obstacle(self, world: np.ndarray, v: float, w: float) -> bool:
        """Whether (v m/s, w rad/s) from ``world`` (3,) gets closer than allowed to obstacles.

        The robot may not enter the inflated obstacles, nor go deeper once inside them.
        """
        grid = self._grid
        horizon = self.config.command_horizon_steps * self._dt
        n = max(2, int(math.ceil(abs(v) * horizon / (0.5 * grid.cell_size))) + 1)
        t = np.linspace(0.0, horizon, n)  # (n,)
        yaw = world[2] + w * t  # (n,)
        if abs(w) > 1e-9:  # unicycle arc
            x = world[0] + v / w * (np.sin(yaw) - math.sin(world[2]))  # (n,)
            y = world[1] - v / w * (np.cos(yaw) - math.cos(world[2]))  # (n,)
        else:
            x = world[0] + v * t * math.cos(world[2])  # (n,)
            y = world[1] + v * t * math.sin(world[2])  # (n,)
        rc = grid.world_to_cell(np.stack([x, y], axis=-1))  # (n, 2)
        inside = grid.in_bounds(rc)  # (n,)
        if not inside.all():
            return True
        clearance = self._clearance[rc[:, 0], rc[:, 1]]  # (n,)
        return bool(clearance[1:].min() < min(0.0, float(clearance[0])))

    def _drive_to(self, world: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Pursuit action (3,) towards world ``target`` (2,) along the cost-aware geodesic."""
        cfg, grid = self.config, self._grid
        if math.dist(world[:2], target) <= cfg.arrive_distance:
            return np.array(_IDLE, np.float32)
        rc = self._cell(world[:2])  # (2,)
        moved = self._target is None or math.dist(target, self._target) > grid.cell_size
        if moved or not field_reaches(self._field, rc):
            self._plan(world, target)
        if not field_reaches(self._field, rc):
            logger.debug("local teacher: no path from %s to %s", world[:2], target)
            return np.array(_IDLE, np.float32)
        if math.dist(world[:2], self._dest) <= cfg.arrive_distance:
            return np.array(_IDLE, np.float32)
        point = path_target(
            self._field,
            grid,
            self._clearance,
            world[:2],
            cfg.lookahead,
            cfg.min_free_clearance,
            end_xy=self._dest,
        )  # (2,)
        v, w = pursuit_command(world, point, self._vmax, self._wmax)
        return command_action(v, w, self._vmax, self._wmax)

    def _cell(self, xy: np.ndarray) -> np.ndarray:
        """Grid cell (2,) of world ``xy`` (2,), clipped into the grid."""
        rc = self._grid.world_to_cell(np.asarray(xy, np.float64))  # (2,)
        return np.clip(rc, 0, np.array(self._grid.shape) - 1)

    def _plan(self, world: np.ndarray, target: np.ndarray) -> None:
        """Cost-to-go field to ``target`` (2,), snapped to a free cell the robot can reach."""
        t0 = time.perf_counter()
        grid = self._grid
        rc = self._cell(world[:2])  # (2,)
        label = int(self._labels[tuple(self._nearest_free[:, rc[0], rc[1]])])
        tc = self._cell(target)  # (2,)
        inside = bool(grid.in_bounds(grid.world_to_cell(np.asarray(target, np.float64))))
        if inside and self._labels[tc[0], tc[1]] == label:
            dest_rc, dest = tc, np.asarray(target, np.float64).copy()
        else:  # snap to the nearest cell the robot fits in and can reach
            nearest = self._nearest_in.get(label)
            if nearest is None:
                nearest = ndimage.distance_transform_edt(
                    self._labels != label, return_distances=False, return_indices=True
                )  # (2, H, W)
                self._nearest_in[label] = nearest
            dest_rc = nearest[:, tc[0], tc[1]]  # (2,)
            dest = grid.cell_to_world(dest_rc)  # (2,)
        sources = np.zeros(grid.shape, bool)  # (H, W)
        sources[dest_rc[0], dest_rc[1]] = True
        self._field = geodesic_distance(self._cost, sources, self._occupancy, grid.cell_size)
        self._target, self._dest = np.asarray(target, np.float64).copy(), dest
        self.replan_seconds.append(time.perf_counter() - t0)
