"""The GR field: the agent's map becomes mass, the mass a potential and a metric, the metric a path.

One :meth:`GRField.update` per planner tick:

1. depth + pose -> map-frame points -> allocentric evidence map (:mod:`.mapping`);
2. masses: goal (attractive), frontier (attractive, so an unseen goal still explores) and
   obstacles (negative density), ``rho`` (B, H, W);
3. potential ``phi`` from the Poisson equation with free-space boundaries;
4. conformal metric ``g = exp(2 psi) delta``, ``psi`` raised near obstacles and low in the
   wells of the attracting (goal + frontier) potential; Christoffel symbols on demand
   (:meth:`GRField.christoffel`);
5. geodesic distance ``T`` of that metric from the goal (or the frontier when no goal is seen)
   by fast marching with cost ``exp(psi)`` around the robot-inflated obstacles;
6. outputs: the next waypoints of the geodesic (B, K, 2) in the robot frame, egocentric
   heading-aligned features (B, C, h, w) and a picture for reports (:meth:`GRField.render`);
   the features and the full potential behind them and the picture are computed when read.
   The allocentric layers are :attr:`GRField.maps` (a :class:`FieldMaps`).

The field owns its state: others read it through ``maps``, ``evidence()`` and ``cell_size``,
edit the map through ``add_obstacle_evidence``, ``forget_obstacle_noise`` and
``mark_unseen_free``, and change the robot radius planning uses through
``set_planning_radius`` (the config is never written).

Next in the data flow: :mod:`vla_gr.core.gr_field.picture` (its top-down picture).
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.core.gr_field.config import FEATURE_NAMES, GRFieldConfig
from vla_gr.core.gr_field.field_maps import FieldMaps, GRFieldOutput
from vla_gr.core.gr_field.mapping import (
    OCC_HITS,
    centred_grid,
    count_obstacle_points,
    empty_map,
    forget_noise,
    map_layers,
    mark_unseen_free,
    update_map,
)
from vla_gr.core.gr_field.physics import (
    christoffel_conformal,
    conformal_log_factor,
    frontier_mask,
    grow_through,
    normalise_mass,
    obstacle_proximity,
    solve_poisson,
)
from vla_gr.core.gr_field.picture import render_field
from vla_gr.geometry.camera import ego_to_world, project_depth, world_to_ego
from vla_gr.geometry.fast_marching import extract_path, geodesic_distance, upwind_gradient
from vla_gr.geometry.grid import inflate_obstacles

logger = logging.getLogger(__name__)

__all__ = ["GRField", "GRFieldOutput", "snap_start"]


def snap_start(travel: np.ndarray, xy: np.ndarray, cell_size: float, radius: float):
    """Where a path from metric point ``xy`` (2,) should start on ``travel`` (H, W).

    ``xy`` itself when its cell is reachable (finite T); otherwise the centre of the nearest
    reachable cell within ``radius`` metres (a robot standing in the inflated margin of an
    obstacle first steps out of it); None when there is none.
    """
    H, W = travel.shape
    r, c = int(np.floor(xy[1] / cell_size)), int(np.floor(xy[0] / cell_size))
    if 0 <= r < H and 0 <= c < W and np.isfinite(travel[r, c]):
        return np.asarray(xy, dtype=np.float64)
    k = int(np.ceil(radius / cell_size)) + 1
    r0, c0 = max(r - k, 0), max(c - k, 0)
    window = travel[r0 : r + k + 1, c0 : c + k + 1]  # (<=2k+1, <=2k+1)
    if window.size == 0:
        return None
    rows, cols = np.nonzero(np.isfinite(window))
    centres = (np.stack([cols + c0, rows + r0], axis=-1) + 0.5) * cell_size  # (M, 2) x, y
    if len(centres) == 0:
        return None
    dist = np.linalg.norm(centres - xy, axis=-1)  # (M,)
    best = int(np.argmin(dist))
    return centres[best] if dist[best] <= radius else None


class GRField(nn.Module):
    """Batched GR field with per-episode map state (see module docstring)."""

    def __init__(self, config: GRFieldConfig | None = None, **overrides) -> None:
        super().__init__()
        if config is None:
            config = GRFieldConfig(**overrides)
        elif overrides:
            raise ValueError("pass either a GRFieldConfig or keyword overrides, not both")
        self.config = config
        self.grid = centred_grid(config.map_size, config.cell_size)
        self.register_buffer("map_state", torch.zeros(0, 4, *self.grid.shape), persistent=False)
        #: obstacle points per sub-cell (B, 1, H * k, W * k), k = clearance_factor (k > 1 only)
        self.register_buffer("sub_hits", self._empty_sub_hits(0), persistent=False)
        self._last: FieldMaps | None = None
        # the robot radius (m) planning uses now: config.robot_radius until
        # set_planning_radius() changes it (the config itself is never written)
        self._planning_radius = float(config.robot_radius)
        #: seconds per part of the last update: mapping, masses, poisson, metric,
        #: fast_marching (inflation + travel time + gradient), path (the features and the full
        #: potential are computed when read, outside the update)
        self.last_timings: dict[str, float] = {}
        #: (rows, cols) of the fast-marching window of each batch element in the last update
        self.planning_windows: list[tuple[int, int]] = []

    @property
    def num_channels(self) -> int:
        return len(FEATURE_NAMES)

    @property
    def cell_size(self) -> float:
        """Metres per map cell."""
        return self.config.cell_size

    @property
    def batch_size(self) -> int:
        """Maps held: 0 before the first update (and after a full reset)."""
        return self.map_state.shape[0]

    @property
    def planning_radius(self) -> float:
        """The robot radius (m) the next update plans for (see :meth:`set_planning_radius`)."""
        return self._planning_radius

    def set_planning_radius(self, radius: float) -> None:
        """Plan for a robot of ``radius`` m from the next update on (the robot's footprint
        marked free, the goal stand-off, where its centre fits, the start's snap distance);
        it holds until set again, across resets; pass ``config.robot_radius`` to restore the
        configured one."""
        radius = float(radius)
        if not (math.isfinite(radius) and radius >= 0.0):
            raise ValueError(f"planning radius {radius} must be finite and >= 0")
        self._planning_radius = radius

    def _empty_sub_hits(self, batch: int) -> torch.Tensor:
        """Zero sub-cell counts (B, 1, H * k, W * k); (B, 1, 0, 0) when k = 1 (not kept)."""
        k = self.config.clearance_factor
        shape = (self.grid.height * k, self.grid.width * k) if k > 1 else (0, 0)
        return torch.zeros(batch, 1, *shape, device=self.map_state.device)

    def reset(self, batch_indices=None) -> None:
        """Clear the map of the given batch elements (all, and forget the batch size, if None)."""
        if batch_indices is None:
            self.map_state = torch.zeros(0, 4, *self.grid.shape, device=self.map_state.device)
            self.sub_hits = self._empty_sub_hits(0)
            self._last = None
            return
        idx = torch.as_tensor(batch_indices, dtype=torch.long).reshape(-1)
        if idx.numel() and (idx.min() < 0 or idx.max() >= self.map_state.shape[0]):
            raise ValueError(
                f"batch_indices {idx.tolist()} out of range for batch {self.map_state.shape[0]}"
            )
        self.map_state[idx.to(self.map_state.device)] = 0.0
        self.sub_hits[idx.to(self.map_state.device)] = 0.0

    # ------------------------------------------------------------------ update

    def _inputs(self, obs: dict, goal_likelihood):
        """Validate and convert observations -> depth (B, H, W), pose (B, 3), goal (B, H*W)."""
        if "depth" not in obs or "pose" not in obs:
            raise ValueError(f"obs must contain 'depth' and 'pose', got keys {sorted(obs)}")
        device = self.map_state.device
        depth = torch.as_tensor(obs["depth"], device=device).float()
        if depth.ndim == 4 and depth.shape[-1] == 1:
            depth = depth[..., 0]
        if depth.ndim != 3:
            raise ValueError(f"obs['depth'] must be (B, H, W[, 1]), got {tuple(depth.shape)}")
        pose = torch.as_tensor(obs["pose"], device=device).float()
        if pose.shape != (depth.shape[0], 3):
            raise ValueError(
                f"obs['pose'] must be (B={depth.shape[0]}, 3), got {tuple(pose.shape)}"
            )
        if not torch.isfinite(pose).all():
            raise ValueError("obs['pose'] contains NaN or inf")
        goal = None
        if goal_likelihood is not None:
            goal = torch.as_tensor(goal_likelihood, device=device).float()
            if goal.ndim == 4 and goal.shape[-1] == 1:
                goal = goal[..., 0]
            if goal.shape != depth.shape:
                raise ValueError(
                    f"goal_likelihood must match depth {tuple(depth.shape)}, "
                    f"got {tuple(goal.shape)}"
                )
            goal = goal.reshape(depth.shape[0], -1)  # (B, H*W)
        return depth, pose, goal

    def project(self, depth: torch.Tensor, pose: torch.Tensor):
        """Map-frame points (B, N, 3) and their validity (B, N) of ``depth`` (B, H, W) metres
        seen from ``pose`` (B, 3) through this field's camera: what :meth:`update` maps."""
        cfg = self.config
        return project_depth(
            depth, cfg.hfov_deg, pose, cfg.camera_height, cfg.camera_forward_offset,
            cfg.min_depth, cfg.max_depth,
        )  # fmt: skip

    def update(
        self, obs: dict, goal_likelihood=None, goal_gate=None, frontier_value=None,
        frontier_keep: float = 0.5, projection=None,
    ) -> GRFieldOutput:  # fmt: skip
        """Integrate one observation per batch element and recompute the field.

        Args:
            obs: dict with ``depth`` (B, H, W, 1) or (B, H, W) metres and ``pose`` (B, 3).
            goal_likelihood: (B, H, W) per-pixel probability that the pixel shows the goal, or
                None (then only the frontier attracts).
            goal_gate: (B, H, W) bool map cells that may count as goal (e.g. cells confirmed
                over several ticks), or None (every cell may). Evidence is still accumulated
                everywhere; the gate only decides which cells attract and are planned to.
            frontier_value: (B, H, W) how much each cell is worth searching, or None (all
                alike). With no goal, the path leads to the frontier cells worth at least
                ``frontier_keep`` times the best frontier cell first, and to any frontier
                cell only when none of those can be reached.
            projection: :meth:`project` of this ``obs`` when the caller has it already (the
                navigator projects the frame for its goal votes first), or None.
        """
        cfg = self.config
        depth, pose, goal = self._inputs(obs, goal_likelihood)
        B = depth.shape[0]
        t0 = time.perf_counter()
        if self.map_state.shape[0] == 0:
            self.map_state = empty_map(B, self.grid, device=self.map_state.device)
            self.sub_hits = self._empty_sub_hits(B)
        elif self.map_state.shape[0] != B:
            raise ValueError(
                f"batch size changed from {self.map_state.shape[0]} to {B}; call reset() first"
            )
        points, valid = self.project(depth, pose) if projection is None else projection
        if points.shape[:2] != valid.shape or valid.shape != (B, depth[0].numel()):
            raise ValueError(
                f"projection must be points (B, N, 3) and valid (B, N) with B, N = {B}, "
                f"{depth[0].numel()}; got {tuple(points.shape)} and {tuple(valid.shape)}"
            )
        heading = torch.stack([torch.cos(pose[:, 2]), torch.sin(pose[:, 2])], dim=-1)  # (B, 2)
        update_map(
            self.map_state, self.grid, points, valid, pose, goal,
            image_shape=tuple(depth.shape[1:]),
            camera_xy=pose[:, :2] + cfg.camera_forward_offset * heading,
            floor_height=cfg.floor_height, max_height=cfg.robot_height,
            robot_radius=self._planning_radius,
        )  # fmt: skip
        if cfg.clearance_factor > 1:
            count_obstacle_points(
                self.sub_hits, self.grid, cfg.clearance_factor, points, valid,
                cfg.floor_height, cfg.robot_height,
            )  # fmt: skip
        self.last_timings = {"mapping": time.perf_counter() - t0}
        if goal_gate is not None:
            goal_gate = torch.as_tensor(goal_gate, device=self.map_state.device).bool()
            if goal_gate.shape != (B, *self.grid.shape):
                raise ValueError(
                    f"goal_gate must be (B, H, W)={(B, *self.grid.shape)}, "
                    f"got {tuple(goal_gate.shape)}"
                )
        if frontier_value is not None:
            frontier_value = torch.as_tensor(frontier_value, device=self.map_state.device)
            if frontier_value.shape != (B, *self.grid.shape):
                raise ValueError(
                    f"frontier_value must be (B, H, W)={(B, *self.grid.shape)}, "
                    f"got {tuple(frontier_value.shape)}"
                )
        return self._compute(pose, goal_gate, frontier_value, frontier_keep)

    def _compute(
        self, pose: torch.Tensor, goal_gate=None, frontier_value=None, frontier_keep=0.5
    ) -> GRFieldOutput:
        """Masses -> potential -> metric -> geodesics -> outputs, from the current map."""
        cfg, h = self.config, self.config.cell_size
        tick = self._stopwatch()
        layers = map_layers(self.map_state)
        occupied, explored = layers["occupied"], layers["explored"]  # (B, H, W) bool
        robot_xy = pose[:, :2] - torch.tensor(
            [self.grid.origin_x, self.grid.origin_y], device=pose.device
        )  # (B, 2) metric from the grid's lower-left corner
        # the robot's own surroundings (under and behind the camera) are no frontier
        frontier = frontier_mask(explored, occupied) & ~self._near(
            robot_xy, cfg.frontier_min_distance
        )  # (B, H, W)
        goal_cells = (layers["goal"] >= cfg.goal_threshold) & explored  # (B, H, W)
        if goal_gate is not None:
            goal_cells = goal_cells & goal_gate  # (B, H, W)
        goal_seen = goal_cells.flatten(1).any(dim=1)  # (B,)

        rho_goal = normalise_mass(layers["goal"] * goal_cells, cfg.goal_mass, h)  # (B, H, W)
        f_total = torch.where(goal_seen, cfg.frontier_mass_goal_seen, cfg.frontier_mass)
        rho_front = normalise_mass(frontier.float(), f_total[:, None, None], h)  # (B, H, W)
        rho_attr = rho_goal + rho_front  # (B, H, W) attracting mass
        rho = rho_attr - cfg.obstacle_density * occupied.float()  # (B, H, W) all mass
        tick("masses")
        # the attracting part shapes the metric; the full potential (features, pictures) is
        # solved only when they are read
        phi_attr = solve_poisson(rho_attr, h, cfg.G)  # (B, H, W)
        tick("poisson")
        proximity = obstacle_proximity(occupied, h, cfg.obstacle_length)  # (B, H, W)
        psi = conformal_log_factor(phi_attr, proximity, cfg.beta, cfg.kappa)  # (B, H, W)
        cost = torch.exp(psi) * (1.0 + (cfg.unknown_cost - 1.0) * (~explored).float())

        # goals sit on obstacles: the robot's centre reaches the free cells within its radius,
        # grown from the goal one cell at a time so that the halo never crosses a wall
        steps = math.ceil((self._planning_radius + h) / h)
        halo = grow_through(goal_cells, goal_cells | ~occupied, steps)  # (B, H, W)
        standoff = halo & explored & ~occupied  # (B, H, W) seen free cells beside the goal
        has_standoff = standoff.flatten(1).any(dim=1)[:, None, None]  # (B, 1, 1)
        goal_src = torch.where(has_standoff, standoff, goal_cells)  # (B, H, W)
        goal_src = goal_src & goal_seen[:, None, None]  # (B, H, W)
        tick("metric")
        # the goal if seen and reachable, else the frontier (explore until a way opens)
        sources = [goal_src, frontier]
        if frontier_value is not None:  # the frontier worth searching first
            worth = torch.where(frontier, frontier_value, -torch.inf)  # (B, H, W)
            best = worth.flatten(1).max(dim=1).values[:, None, None]  # (B, 1, 1)
            sources.insert(1, frontier & (worth >= frontier_keep * best))  # (B, H, W)
        travel, grads, choice = self._travel(cost, occupied, explored, sources, robot_xy)
        tick("fast_marching")  # travel (B, H, W), grads (B, 2, H, W), choice (B,)
        waypoints, has_path, distance = self._waypoints(travel, grads, robot_xy, pose)
        tick("path")
        self._last = last = FieldMaps(
            psi=psi, travel=travel, occupied=occupied, explored=explored, frontier=frontier,
            goal=goal_cells, robot_xy=robot_xy, yaw=pose[:, 2], has_path=has_path,
            rho=rho, cell_size=h, G=cfg.G,
        )  # fmt: skip
        goal_layer = layers["goal"]

        def features() -> torch.Tensor:  # (B, C, h, w) from this tick's maps
            t_feat = torch.where(
                torch.isfinite(travel), (travel / cfg.travel_clip).clamp(max=1.0), 1.0
            )  # (B, H, W)
            allo = torch.stack(
                [last.phi_hat, psi, t_feat, grads[:, 0], grads[:, 1],
                 occupied.float(), explored.float(), goal_layer, frontier.float()], dim=1,
            )  # (B, C, H, W)  # fmt: skip
            return self._egocentric(allo, pose)

        return GRFieldOutput(features, waypoints, has_path, (choice == 0) & has_path, distance)

    def _stopwatch(self):
        """A callable ``tick(name)`` that stores the seconds since the previous tick as ``name``."""
        last = [time.perf_counter()]

        def tick(name: str) -> None:
            now = time.perf_counter()
            self.last_timings[name] = now - last[0]
            last[0] = now

        return tick

    def _near(self, xy: torch.Tensor, radius: float) -> torch.Tensor:
        """(B, H, W) bool: cell centres within ``radius`` of metric points ``xy`` (B, 2)."""
        h, (H, W) = self.grid.cell_size, self.grid.shape
        cx = (torch.arange(W, device=xy.device, dtype=xy.dtype) + 0.5) * h  # (W,)
        cy = (torch.arange(H, device=xy.device, dtype=xy.dtype) + 0.5) * h  # (H,)
        dx = cx[None, None, :] - xy[:, 0, None, None]  # (B, 1, W)
        dy = cy[None, :, None] - xy[:, 1, None, None]  # (B, H, 1)
        return dx**2 + dy**2 <= radius**2  # (B, H, W)

    def _travel(self, cost, occupied, explored, candidates, robot_xy):
        """Geodesic distance T (B, H, W), its unit upwind gradient (B, 2, H, W) and the index
        (B,) of the source set used (-1: none reaches the robot).

        ``candidates`` is a list of source masks (B, H, W) in order of preference (goal, then
        frontier); the first one whose front reaches the robot's cell is used. Fast marching
        runs on the bounding box of the explored cells grown by ``planning_margin`` (sources
        and robot lie inside it); T is inf outside.
        """
        cfg, h = self.config, self.config.cell_size
        B = cost.shape[0]
        travel = np.full(cost.shape, np.inf)
        grads = np.zeros((B, 2, *cost.shape[1:]))
        choice = np.full(B, -1)
        cost_np, occ_np = cost.detach().cpu().numpy(), occupied.cpu().numpy()
        cand_np = [c.cpu().numpy() for c in candidates]
        robot_np, seen_np = robot_xy.detach().cpu().numpy(), explored.cpu().numpy()
        pad = math.ceil(cfg.planning_margin / h)
        self.planning_windows = [(0, 0)] * B
        for b in range(B):
            rows, cols = np.nonzero(seen_np[b] | np.any([c[b] for c in cand_np], axis=0))
            if len(rows) == 0:
                continue
            win = (
                slice(max(rows.min() - pad, 0), rows.max() + pad + 1),
                slice(max(cols.min() - pad, 0), cols.max() + pad + 1),
            )
            occ = occ_np[b][win]  # (h', w') planning window
            self.planning_windows[b] = occ.shape
            inflated = self._no_fit(b, occ, win)  # (h', w')
            corner = np.array([win[1].start, win[0].start]) * h  # window's corner, metres
            for i, sources in enumerate(cand_np):
                src = sources[b][win]  # (h', w')
                if not src.any():
                    continue
                if (src & ~inflated).any():  # prefer sources where the robot's centre fits
                    src = src & ~inflated
                T = geodesic_distance(cost_np[b][win], src, inflated & ~src, h)  # (h', w')
                reached = snap_start(T, robot_np[b] - corner, h, self._snap_radius) is not None
                if reached or not np.isfinite(travel[b]).any():
                    gx, gy = upwind_gradient(T, h)
                    norm = np.maximum(np.hypot(gx, gy), 1e-12)
                    travel[b][win], grads[b, 0][win], grads[b, 1][win] = T, gx / norm, gy / norm
                if reached:
                    choice[b] = i
                    break
        return (
            torch.from_numpy(travel).float().to(cost.device),
            torch.from_numpy(grads).float().to(cost.device),
            torch.from_numpy(choice).to(cost.device),
        )

    def _no_fit(self, b: int, occ: np.ndarray, win: tuple[slice, slice]) -> np.ndarray:
        """Cells (h', w') of window ``win`` (occupancy ``occ`` (h', w')) of batch element ``b``
        where the robot's centre does not fit.

        An occupied cell may be filled up to its edge, so a free cell fits only when its centre
        clears every occupied cell's centre by the radius + h / 2. With ``clearance_factor`` k
        > 1 the test runs on sub-cells of h / k, on the obstacle points each sub-cell counted
        (an occupied cell without any, evidence written to the map directly, is filled whole;
        :meth:`add_obstacle_evidence` fills the sub-cells too), with the margin of
        a sub-cell's corner (radius + h / k / sqrt(2), + ``clearance_margin``): a free cell
        fits when any of its sub-cells does, so a gap is judged by where its edges are, not by
        the cells they fall in. Occupied cells never fit.
        """
        cfg, h, k = self.config, self.config.cell_size, self.config.clearance_factor
        if k == 1:
            return inflate_obstacles(occ, self._planning_radius + 0.5 * h, h)
        rows, cols = occ.shape
        r0, c0 = win[0].start * k, win[1].start * k
        sub = self.sub_hits[b, 0, r0 : r0 + rows * k, c0 : c0 + cols * k].cpu().numpy() > 0
        sub = sub.reshape(rows, k, cols, k)  # (h', k, w', k) points per sub-cell
        filled = occ & ~sub.any(axis=(1, 3))  # (h', w') occupied cells with no point
        sub_occ = (sub & occ[:, None, :, None]) | filled[:, None, :, None]  # (h', k, w', k)
        sub_occ = sub_occ.reshape(rows * k, cols * k)
        radius = self._planning_radius + h / k / math.sqrt(2.0) + cfg.clearance_margin
        no_fit = inflate_obstacles(sub_occ, radius, h / k)
        return occ | no_fit.reshape(rows, k, cols, k).all(axis=(1, 3))

    # ------------------------------------------------------------------ map edits

    def _map(self, index: int) -> torch.Tensor:
        """The evidence map (4, H, W) of batch element ``index`` (a view: edits write it)."""
        if not 0 <= index < self.map_state.shape[0]:
            raise ValueError(f"no map {index} in a batch of {self.map_state.shape[0]}")
        return self.map_state[index]  # (4, H, W)

    def evidence(self, index: int = 0) -> torch.Tensor:
        """A copy (4, H, W) of the evidence counts of batch element ``index``, channels
        :data:`~vla_gr.core.gr_field.mapping.OCC_HITS` etc."""
        return self._map(index).clone()  # (4, H, W)

    def forget_obstacle_noise(self, max_hits: float, free_ratio: float, index: int = 0) -> None:
        """Drop the obstacle evidence of cells of batch element ``index`` with at most
        ``max_hits`` hits that ``free_ratio`` times as many free-space hits outvote
        (:func:`~vla_gr.core.gr_field.mapping.forget_noise`); sub-cell counts stay."""
        forget_noise(self._map(index), max_hits, free_ratio)

    def mark_unseen_free(self, cells: torch.Tensor, index: int = 0) -> None:
        """Count the ``cells`` (D, 2) as (row, col) of batch element ``index`` that hold no
        evidence yet as seen free (one free-space hit); cells seen before are left alone."""
        mark_unseen_free(self._map(index), cells)

    def add_obstacle_evidence(self, cells: torch.Tensor, hits: float, index: int = 0) -> None:
        """Add ``hits`` (negative: take back) of obstacle evidence to the distinct ``cells``
        (D, 2) as (row, col) of batch element ``index``, and to each of their sub-cells;
        counts stay >= 0."""
        occ = self._map(index)[OCC_HITS]  # (H, W)
        occ[cells[:, 0], cells[:, 1]] += hits
        occ.clamp_(min=0.0)
        k = self.config.clearance_factor
        if k > 1:
            offs = torch.arange(k, device=cells.device)  # (k,)
            rows = (cells[:, 0, None] * k + offs)[:, :, None]  # (D, k, 1)
            cols = (cells[:, 1, None] * k + offs)[:, None, :]  # (D, 1, k)
            sub = self.sub_hits[index, 0]  # (H * k, W * k)
            sub[rows, cols] += hits
            sub.clamp_(min=0.0)

    def _waypoints(self, travel, grads, robot_xy, pose):
        """Resample the descent path at ``waypoint_spacing``: (B, K, 2) robot frame, (B,), (B,)."""
        cfg, h = self.config, self.config.cell_size
        K, ds = cfg.num_waypoints, cfg.waypoint_spacing
        B = travel.shape[0]
        out = torch.zeros(B, K, 2)
        has_path = torch.zeros(B, dtype=torch.bool)
        distance = torch.full((B,), math.inf)
        T_np, robot_np = travel.cpu().numpy(), robot_xy.detach().cpu().numpy()
        g_np = grads.cpu().numpy()  # (B, 2, H, W)
        for b in range(B):
            start = snap_start(T_np[b], robot_np[b], h, self._snap_radius)
            if start is None:
                continue
            path = extract_path(
                T_np[b], start, h, cfg.path_step, max_length=K * ds + h,
                gradient=(g_np[b, 0], g_np[b, 1]),
            )  # fmt: skip
            if len(path) == 0:
                continue
            if not np.allclose(start, robot_np[b]):  # leave the inflated zone first
                path = np.concatenate([robot_np[b][None], path])
            seg = np.linalg.norm(np.diff(path, axis=0), axis=1)  # (N - 1,)
            arc = np.concatenate([[0.0], np.cumsum(seg)])  # (N,)
            r, c = np.floor(path[-1][::-1] / h).astype(int)
            reached = T_np[b][r, c] == 0.0 or arc[-1] >= K * ds - 1e-6
            if not reached:
                continue
            s = np.minimum(np.arange(1, K + 1) * ds, arc[-1])  # (K,)
            pts = np.stack([np.interp(s, arc, path[:, 0]), np.interp(s, arc, path[:, 1])], -1)
            out[b] = torch.from_numpy(pts).float()  # (K, 2) metric from grid corner
            has_path[b] = True
            r0, c0 = np.floor(start[::-1] / h).astype(int)
            distance[b] = float(T_np[b][r0, c0])
        if not has_path.all():
            logger.debug("GR field: no path for batch elements %s", (~has_path).nonzero().flatten())
        origin = torch.tensor([self.grid.origin_x, self.grid.origin_y])
        ego = world_to_ego((out + origin).to(pose.device), pose)  # (B, K, 2)
        ego = torch.where(has_path.to(pose.device)[:, None, None], ego, 0.0)
        return ego, has_path.to(pose.device), distance.to(pose.device)

    def _egocentric(self, allo: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """Rotate/crop allocentric maps (B, C, H, W) into the robot frame -> (B, C, h, w).

        The output follows the GridSpec convention in the robot frame: columns run forward,
        rows run left, the robot sits at the centre. Vector channels are rotated too.
        """
        cfg = self.config
        n, ec = cfg.ego_size, cfg.ego_cell_size or cfg.cell_size
        B = allo.shape[0]
        offs = (torch.arange(n, device=allo.device, dtype=allo.dtype) + 0.5 - n / 2) * ec  # (n,)
        left, fwd = torch.meshgrid(offs, offs, indexing="ij")  # (n, n) each
        ego = torch.stack([fwd, left], dim=-1).reshape(1, -1, 2).expand(B, -1, -1)  # (B, n*n, 2)
        world = ego_to_world(ego, pose.to(allo.dtype))  # (B, n*n, 2)
        g = self.grid
        gx = 2.0 * (world[..., 0] - g.origin_x) / (g.width * g.cell_size) - 1.0  # (B, n*n)
        gy = 2.0 * (world[..., 1] - g.origin_y) / (g.height * g.cell_size) - 1.0  # (B, n*n)
        grid = torch.stack([gx, gy], dim=-1).reshape(B, n, n, 2)  # (B, n, n, 2)
        feats = F.grid_sample(
            allo, grid, mode="bilinear", padding_mode="zeros", align_corners=False
        )
        inside = ((gx.abs() <= 1) & (gy.abs() <= 1)).reshape(B, 1, n, n).to(allo.dtype)
        t = FEATURE_NAMES.index("travel")
        feats[:, t : t + 1] = feats[:, t : t + 1] * inside + (1.0 - inside)
        c, s = torch.cos(pose[:, 2])[:, None, None], torch.sin(pose[:, 2])[:, None, None]
        i = FEATURE_NAMES.index("grad_forward")
        gxw, gyw = feats[:, i].clone(), feats[:, i + 1].clone()  # (B, n, n) map-frame components
        feats[:, i], feats[:, i + 1] = c * gxw + s * gyw, -s * gxw + c * gyw
        return feats  # (B, C, n, n)

    # ------------------------------------------------------------------ extras

    @property
    def _snap_radius(self) -> float:
        """How far (m) the robot may be from a cell its centre fits in (mapping slack)."""
        return self._planning_radius + 1.5 * self.config.cell_size

    @property
    def maps(self) -> FieldMaps:
        """The allocentric layers of the last update (see :class:`FieldMaps` for each one's
        shape); read them, never write them."""
        if self._last is None:
            raise RuntimeError("GRField.maps needs a prior update()")
        return self._last

    def christoffel(self) -> torch.Tensor:
        """Christoffel symbols (B, 2, 2, 2, H, W) of the last metric (call after update)."""
        if self._last is None:
            raise RuntimeError("GRField.christoffel() needs a prior update()")
        return christoffel_conformal(self._last.psi, self.config.cell_size)

    def render(self, index: int = 0, scale: int = 2) -> np.ndarray:
        """Top-down picture (H * scale, W * scale, 3) uint8 of batch element ``index``.

        Background: potential; dark: unexplored; black: obstacles; cyan: frontier; red: goal;
        white: the full geodesic path from the robot (orange) to the source.
        """
        if self._last is None:
            raise RuntimeError("GRField.render() needs a prior update()")
        last, h = self._last, self.config.cell_size
        if not 0 <= index < last.travel.shape[0]:
            raise ValueError(f"index={index} out of range for batch {last.travel.shape[0]}")
        robot = last.robot_xy[index].cpu().numpy()  # (2,) metric
        path = None
        if bool(last.has_path[index]):
            metric = extract_path(last.travel[index].cpu().numpy(), robot, h, 0.5)  # (N, 2)
            path = metric[:, ::-1] / h - 0.5  # (N, 2) fractional (row, col)
        return render_field(
            last.phi_hat[index].cpu().numpy(), last.occupied[index].cpu().numpy(),
            last.explored[index].cpu().numpy(), last.frontier[index].cpu().numpy(),
            last.goal[index].cpu().numpy(), path,
            (robot[1] / h - 0.5, robot[0] / h - 0.5), float(last.yaw[index]), scale,
        )  # fmt: skip
