"""A fine local planner for gaps the coarse map cannot resolve (``navigator.local_planner``).

The GR field plans on 0.15 m cells, so a gap a few centimetres wider than the robot is either
closed (at the real radius) or opened for a robot much thinner than the real one (the
navigator's ``tight.radius``), whose path then runs into the furniture it hugs. This planner
keeps the obstacle points of every depth frame on fine cells (``cell``, 0.025 m by default) and,
while the navigator plans thin, re-plans the way out at the real radius (its settings are
``model.navigator.local_planner.*``,
:class:`~vla_gr.agent.navigator.config.LocalPlannerConfig`):

1. a window of ``window`` metres around the robot; a fine cell is free when it is farther
   than ``robot_radius + margin`` from every fine cell with at least ``min_hits`` obstacle
   points (coarse occupied cells without any point, the navigator's marked obstacles, are
   filled whole);
2. fast marching from the robot over the free fine cells gives the path length L to each;
3. the coarse field's travel time T to the goal or frontier (the thin robot's plan) scores
   each reachable fine cell on the window's rim, and each source of the field (T = 0)
   inside it, by L + T; the best, if it gets the robot at least ``min_progress`` metres
   nearer in T, is the local target;
4. the path to it descends a second fast-marching field from the robot, slower near
   obstacles (``clearance_cost``), so it runs through the middle of a gap.

Unseen fine cells count as free (the depth check of the follower still guards). A plan is
followed for up to ``replan_ticks`` ticks while the robot keeps to it.
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch
from scipy import ndimage

from vla_gr.agent.navigator.config import LocalPlannerConfig
from vla_gr.core.gr_field.mapping import count_obstacle_points
from vla_gr.geometry.fast_marching import extract_path, geodesic_distance
from vla_gr.geometry.grid import GridSpec

__all__ = ["LocalPlanner"]


class LocalPlanner:
    """Fine obstacle points of one episode and the local re-plan on them (batch 1).

    Args:
        grid: the coarse map's grid; the fine cells split each of its cells k x k,
            k = round(cell_size / config.cell).
        robot_radius: metres, the real robot's.
        config: its settings (``model.navigator.local_planner``).
        floor_height, robot_height: the obstacle band of the depth points (metres).
    """

    def __init__(
        self,
        grid: GridSpec,
        robot_radius: float,
        config: LocalPlannerConfig,
        floor_height: float,
        robot_height: float,
    ) -> None:
        self.grid = grid
        self.config = config
        self.k = max(1, round(grid.cell_size / config.cell))
        self.cell = grid.cell_size / self.k  # metres per fine cell
        self.radius = robot_radius + config.margin
        self.band = (floor_height, robot_height)
        self.hits = torch.zeros(1, 1, grid.height * self.k, grid.width * self.k)
        self._path: np.ndarray | None = None  # (N, 2) the path being followed
        self._age = 0  # ticks it has been followed
        self.last_plan_seconds = 0.0  # time :meth:`plan` took this tick (0: did not plan)

    def reset(self) -> None:
        self.hits.zero_()
        self.forget()

    def forget(self) -> None:
        """Drop the path being followed (the next :meth:`follow` plans anew)."""
        self._path, self._age = None, 0

    def follow(
        self, robot_xy: np.ndarray, travel: np.ndarray, occupied: np.ndarray
    ) -> np.ndarray | None:
        """The path to follow this tick, (N, 2) from the grid corner, or None: the last plan's
        rest while it is younger than ``replan_ticks``, the robot within ``off_path`` of it and
        its end still ``min_progress`` away; else a new :meth:`plan` (arguments as there)."""
        cfg = self.config
        if self._path is not None and self._age < cfg.replan_ticks:
            gaps = np.linalg.norm(self._path - robot_xy, axis=-1)  # (N,)
            rest = self._path[int(np.argmin(gaps)) :]  # (M, 2)
            ahead = float(np.linalg.norm(rest[-1] - robot_xy))
            on_path = gaps.min() <= cfg.off_path and len(rest) > 1
            if on_path and ahead >= cfg.min_progress:
                self._age += 1
                return rest
        t0 = time.perf_counter()
        self._path, self._age = self.plan(robot_xy, travel, occupied), 1
        self.last_plan_seconds = time.perf_counter() - t0
        return self._path

    def observe(self, points: torch.Tensor, valid: torch.Tensor) -> None:
        """Count this frame's obstacle-band points (1, N, 3) (map frame) on the fine cells;
        called once per tick, first."""
        self.last_plan_seconds = 0.0
        count_obstacle_points(self.hits, self.grid, self.k, points, valid, *self.band)

    def plan(
        self, robot_xy: np.ndarray, travel: np.ndarray, occupied: np.ndarray
    ) -> np.ndarray | None:
        """The local path (N, 2), metric from the grid corner, from the robot towards the best
        fine cell of the window; None when no fine cell gets nearer in ``travel``.

        Args:
            robot_xy: (2,) metres from the grid's lower-left corner.
            travel: (H, W) the coarse field's travel time (inf: unreachable or outside).
            occupied: (H, W) bool, the coarse occupied cells.
        """
        cfg, k, f = self.config, self.k, self.cell
        n = int(math.ceil(cfg.window / f))
        H, W = self.hits.shape[-2:]
        rr, rc = int(robot_xy[1] / f), int(robot_xy[0] / f)  # robot's fine cell
        r0, r1 = max(rr - n, 0), min(rr + n + 1, H)
        c0, c1 = max(rc - n, 0), min(rc + n + 1, W)
        points = self.hits[0, 0, r0:r1, c0:c1].numpy() >= cfg.min_hits  # (h, w) obstacles
        rows, cols = np.arange(r0, r1) // k, np.arange(c0, c1) // k  # coarse cell of each
        coarse_occ = occupied[np.ix_(rows, cols)]  # (h, w)
        block = self.hits[0, 0, rows[0] * k : (rows[-1] + 1) * k, cols[0] * k : (cols[-1] + 1) * k]
        # a coarse cell with points (even too few to count) is not a marked obstacle
        with_points = _any_in_cell(block.numpy() > 0, k)  # (rows, cols) of the coarse block
        filled = coarse_occ & ~with_points[np.ix_(rows - rows[0], cols - cols[0])]
        obstacle = points | filled  # (h, w)
        clearance = ndimage.distance_transform_edt(~obstacle) * f  # (h, w) metres
        free = clearance > self.radius
        here = (rr - r0, rc - c0)
        yy, xx = np.ogrid[r0:r1, c0:c1]
        near = (yy - rr) ** 2 + (xx - rc) ** 2 <= (cfg.start_radius / f) ** 2
        free |= near & ~obstacle  # the robot may leave where it stands
        # slower near obstacles: 1 + clearance_cost at the limit, 1 from 0.15 m beyond
        spare = np.clip(1.0 - (clearance - self.radius) / 0.15, 0.0, 1.0)  # (h, w)
        cost = 1.0 + cfg.clearance_cost * spare
        source = np.zeros_like(free)
        source[here] = True
        # the target by length (a cost above 1 would make stopping short of a gap look best),
        # the way to it by cost (through the middle of the gap)
        length = geodesic_distance(1.0, source, ~free, f)  # (h, w) metres
        T = travel[np.ix_(rows, cols)]  # (h, w) coarse travel time of each fine cell
        # targets: the window's rim, or the field's own sources (T = 0: a goal or frontier
        # inside the window); an inner cell would win on T's coarse steps alone
        rim = np.zeros_like(free)
        rim[:2], rim[-2:], rim[:, :2], rim[:, -2:] = True, True, True, True
        target = (rim | (T == 0.0)) & np.isfinite(length + T)
        score = np.where(target, length + T, np.nan)  # (h, w)
        if np.isnan(score).all():
            return None
        best = np.unravel_index(np.nanargmin(score), score.shape)
        t_here = travel[rr // k, rc // k]
        progress = (t_here - T[best]) if np.isfinite(t_here) else math.inf
        if progress < cfg.min_progress or length[best] < cfg.min_progress:
            return None
        D = geodesic_distance(cost, source, ~free, f)  # (h, w) travel cost from the robot
        start = (np.array([best[1], best[0]]) + 0.5) * f  # (2,) metric within the window
        path = extract_path(D, start, f, 1.0)  # (N, 2) from the target back to the robot
        if len(path) < 2:
            return None
        corner = np.array([c0, r0]) * f
        return np.asarray(path)[::-1] + corner  # (N, 2) robot -> target, from the grid corner


def _any_in_cell(fine: np.ndarray, k: int) -> np.ndarray:
    """(H, W) bool: coarse cells with any true fine cell of ``fine`` (H * k, W * k)."""
    H, W = fine.shape[0] // k, fine.shape[1] // k
    return fine.reshape(H, k, W, k).any(axis=(1, 3))
