"""The agent's allocentric top-down map, accumulated from depth (and goal likelihood) images.

The map is anchored at the episode start and laid out as a ``GridSpec`` (rows along +y,
cols along +x). Its state is a float tensor (B, 4, H, W) of evidence counts, so views from
different poses simply add up:

- ``OCC_HITS``: points inside the obstacle height band (floor + margin .. robot height);
- ``FREE_HITS``: floor points, free-space ray samples and the robot's own footprint;
- ``GOAL_SUM``: sum of the goal likelihood of the points that landed in the cell;
- ``POINT_HITS``: number of points that landed in the cell, so ``GOAL_SUM / POINT_HITS`` is
  the mean goal likelihood of what was seen there (a cell shared by a thin wall and the goal
  object in front of it is not all goal).

Next in the data flow: :mod:`vla_gr.core.gr_field.physics` (masses, potential, metric).
"""

from __future__ import annotations

import math

import torch

from vla_gr.geometry.grid import GridSpec
from vla_gr.geometry.robot_spec import ROBOT_RADIUS

OCC_HITS, FREE_HITS, GOAL_SUM, POINT_HITS = range(4)
NUM_MAP_CHANNELS = 4


def centred_grid(size: int, cell_size: float) -> GridSpec:
    """A square ``size`` x ``size`` grid centred on the episode start (the map-frame origin)."""
    half = size * cell_size / 2.0
    return GridSpec(origin_x=-half, origin_y=-half, cell_size=cell_size, height=size, width=size)


def empty_map(batch: int, grid: GridSpec, device=None) -> torch.Tensor:
    """Zero evidence (B, 4, H, W) float32."""
    return torch.zeros(batch, NUM_MAP_CHANNELS, grid.height, grid.width, device=device)


def points_to_cells(points_xy: torch.Tensor, grid: GridSpec) -> tuple[torch.Tensor, torch.Tensor]:
    """Metric points (..., 2) as (x, y) -> cells (..., 2) as (row, col), in-bounds mask (...)."""
    col = torch.floor((points_xy[..., 0] - grid.origin_x) / grid.cell_size).long()  # (...)
    row = torch.floor((points_xy[..., 1] - grid.origin_y) / grid.cell_size).long()  # (...)
    inside = (row >= 0) & (row < grid.height) & (col >= 0) & (col < grid.width)
    return torch.stack([row, col], dim=-1), inside


def _scatter(
    state: torch.Tensor, grid: GridSpec, xy, mask, channel: int, values, reduce: str = "sum"
) -> None:
    """Add (or max, ``reduce="amax"``) ``values`` (B, N) at points ``xy`` (B, N, 2) where
    ``mask`` (B, N) into ``channel`` of ``state`` (B, C, H, W), in place."""
    cells, inside = points_to_cells(xy, grid)  # (B, N, 2), (B, N)
    _scatter_cells(state, cells, mask & inside, channel, values, reduce)


def _scatter_cells(
    state: torch.Tensor, cells, keep, channel: int, values, reduce: str = "sum"
) -> None:
    """Add (or max) ``values`` (B, N) at in-bounds ``cells`` (B, N, 2) as (row, col) where
    ``keep`` (B, N) into ``channel`` of ``state`` (B, C, H, W), in place."""
    B, C, H, W = state.shape
    batch = torch.arange(B, device=state.device)[:, None]  # (B, 1)
    flat = batch * (C * H * W) + channel * H * W + cells[..., 0] * W + cells[..., 1]  # (B, N)
    view = state.view(-1)  # (B*C*H*W,)
    view.scatter_reduce_(0, flat[keep], values[keep].to(state.dtype), reduce=reduce)


def free_space_rays(
    points: torch.Tensor,
    valid: torch.Tensor,
    camera_xy: torch.Tensor,
    image_shape: tuple[int, int],
    floor_height: float,
    step: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Samples along each image column's horizontal ray up to the first obstacle.

    A column's ray ends half a step before its nearest in-band (height >= ``floor_height``)
    point; a column that sees only floor is free up to its farthest floor point.

    Args:
        points: (B, N, 3) map-frame points, N = Hi * Wi in row-major pixel order.
        valid: (B, N) bool.
        camera_xy: (B, 2) optical centre in the map frame.
        image_shape: (Hi, Wi).
        floor_height: points below this height are floor.
        step: spacing of the samples along a ray (m).

    Returns:
        samples (B, Wi * S, 2) metric positions and their mask (B, Wi * S).
    """
    B = points.shape[0]
    Hi, Wi = image_shape
    pts = points.view(B, Hi, Wi, 3)  # (B, Hi, Wi, 3)
    ok = valid.view(B, Hi, Wi)  # (B, Hi, Wi)
    rel = pts[..., :2] - camera_xy[:, None, None, :]  # (B, Hi, Wi, 2)
    dist = rel.norm(dim=-1)  # (B, Hi, Wi)
    is_obstacle = ok & (pts[..., 2] >= floor_height)  # (B, Hi, Wi)
    is_floor = ok & ~is_obstacle  # (B, Hi, Wi)
    inf = torch.full_like(dist, math.inf)
    nearest_obstacle = torch.where(is_obstacle, dist, inf).amin(dim=1)  # (B, Wi)
    farthest_floor = torch.where(is_floor, dist, torch.zeros_like(dist)).amax(dim=1)  # (B, Wi)
    extent = torch.where(
        torch.isfinite(nearest_obstacle), nearest_obstacle - 0.5 * step, farthest_floor
    )  # (B, Wi)
    # every valid pixel of a column has the same bearing; take the unit direction of any of them
    unit = rel / dist.clamp_min(1e-9)[..., None]  # (B, Hi, Wi, 2)
    weight = ok.to(unit.dtype)[..., None]  # (B, Hi, Wi, 1)
    direction = (unit * weight).sum(dim=1)  # (B, Wi, 2)
    direction = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-9)  # (B, Wi, 2)
    has_ray = ok.any(dim=1)  # (B, Wi)
    max_extent = float(extent.max().clamp_min(0)) if extent.numel() else 0.0
    S = max(1, math.ceil(max_extent / step))
    t = (torch.arange(S, device=points.device, dtype=points.dtype) + 0.5) * step  # (S,)
    samples = camera_xy[:, None, None, :] + direction[:, :, None, :] * t[None, None, :, None]
    mask = has_ray[..., None] & (t[None, None, :] <= extent[..., None])  # (B, Wi, S)
    return samples.reshape(B, -1, 2), mask.reshape(B, -1)


def update_map(
    state: torch.Tensor,
    grid: GridSpec,
    points: torch.Tensor,
    valid: torch.Tensor,
    pose: torch.Tensor,
    goal_likelihood: torch.Tensor | None = None,
    *,
    image_shape: tuple[int, int] | None = None,
    camera_xy: torch.Tensor | None = None,
    floor_height: float = 0.1,
    max_height: float = 1.2,
    robot_radius: float = ROBOT_RADIUS,
) -> torch.Tensor:
    """Accumulate one batch of views into the evidence map ``state`` (in place; also returned).

    Args:
        state: (B, 4, H, W) evidence counts (see module docstring).
        grid: placement of the map in the episode-start frame.
        points: (B, N, 3) map-frame points (x, y, height) from ``project_depth``.
        valid: (B, N) bool; invalid points are ignored.
        pose: (B, 3) robot pose (x, y, yaw); its footprint disk is marked free.
        goal_likelihood: (B, N) per-point goal probability in [0, 1], or None.
        image_shape: (Hi, Wi) of the depth image; enables free-space ray casting.
        camera_xy: (B, 2) optical centre; defaults to the pose position.
        floor_height: points below are floor (free); above (up to ``max_height``) obstacles.
        max_height: points above are ignored for occupancy (overhangs the robot passes under).
        robot_radius: radius (m) of the footprint marked free; 0 disables.

    Returns:
        ``state``.
    """
    if state.ndim != 4 or state.shape[1] != NUM_MAP_CHANNELS:
        raise ValueError(f"state must be (B, {NUM_MAP_CHANNELS}, H, W), got {tuple(state.shape)}")
    if state.shape[-2:] != grid.shape:
        raise ValueError(f"state grid {tuple(state.shape[-2:])} does not match grid {grid.shape}")
    if points.shape[:2] != valid.shape or points.shape[0] != state.shape[0]:
        raise ValueError(
            f"points {tuple(points.shape)}, valid {tuple(valid.shape)} and state batch "
            f"{state.shape[0]} disagree"
        )
    if not floor_height < max_height:
        raise ValueError(f"floor_height={floor_height} must be < max_height={max_height}")
    points = points.to(state.dtype)
    xy, z = points[..., :2], points[..., 2]  # (B, N, 2), (B, N)
    obstacle = obstacle_band(points, valid, floor_height, max_height)  # (B, N)
    floor = valid & (z < floor_height)  # (B, N)
    ones = torch.ones_like(z)  # (B, N)
    cells, inside = points_to_cells(xy, grid)  # (B, N, 2), (B, N): once for every layer
    _scatter_cells(state, cells, obstacle & inside, OCC_HITS, ones)
    _scatter_cells(state, cells, floor & inside, FREE_HITS, ones)
    _scatter_cells(state, cells, valid & inside, POINT_HITS, ones)
    if goal_likelihood is not None:
        if goal_likelihood.shape != valid.shape:
            raise ValueError(
                f"goal_likelihood must be (B, N)={tuple(valid.shape)}, "
                f"got {tuple(goal_likelihood.shape)}"
            )
        like = torch.nan_to_num(goal_likelihood.to(state.dtype), nan=0.0).clamp(0.0, 1.0)
        _scatter_cells(state, cells, valid & inside, GOAL_SUM, like)
    if image_shape is not None:
        cam = pose[:, :2].to(state.dtype) if camera_xy is None else camera_xy.to(state.dtype)
        samples, mask = free_space_rays(
            points, valid, cam, image_shape, floor_height, 0.5 * grid.cell_size
        )  # (B, M, 2), (B, M)
        _scatter(state, grid, samples, mask, FREE_HITS, torch.ones_like(mask, dtype=state.dtype))
    if robot_radius > 0:
        k = math.ceil(robot_radius / grid.cell_size)
        offs = torch.arange(-k, k + 1, device=state.device, dtype=state.dtype) * grid.cell_size
        dy, dx = torch.meshgrid(offs, offs, indexing="ij")
        disk = (dx**2 + dy**2) <= robot_radius**2  # (K, K)
        rel = torch.stack([dx[disk], dy[disk]], dim=-1)  # (D, 2)
        foot = pose[:, None, :2].to(state.dtype) + rel[None]  # (B, D, 2)
        mask = torch.ones(foot.shape[:2], dtype=torch.bool, device=state.device)  # (B, D)
        _scatter(state, grid, foot, mask, FREE_HITS, torch.ones_like(mask, dtype=state.dtype))
    return state


def obstacle_band(
    points: torch.Tensor, valid: torch.Tensor, floor_height: float, max_height: float
) -> torch.Tensor:
    """(B, N) bool: the valid points (B, N, 3) between ``floor_height`` and ``max_height``."""
    z = points[..., 2]  # (B, N)
    return valid & (z >= floor_height) & (z <= max_height)


def count_obstacle_points(
    hits: torch.Tensor,
    grid: GridSpec,
    factor: int,
    points: torch.Tensor,
    valid: torch.Tensor,
    floor_height: float,
    max_height: float,
) -> None:
    """Add the obstacle-band points (B, N, 3) to the counts ``hits`` (B, 1, H * k, W * k) of the
    sub-cells that ``factor`` k splits each of ``grid``'s cells into (in place). A point lands
    in a sub-cell of the cell :func:`update_map` puts it in, whatever the rounding."""
    k, h = factor, grid.cell_size
    points = points.to(hits.dtype)  # as update_map reads them
    xy = points[..., :2]  # (B, N, 2)
    cells, inside = points_to_cells(xy, grid)  # (B, N, 2) as (row, col), (B, N)
    keep = obstacle_band(points, valid, floor_height, max_height) & inside  # (B, N)
    offset = torch.stack(
        [
            (xy[..., 1] - grid.origin_y) / h - cells[..., 0],
            (xy[..., 0] - grid.origin_x) / h - cells[..., 1],
        ],
        dim=-1,
    )  # (B, N, 2) position within the cell, [0, 1)
    sub = cells * k + (offset * k).floor().long().clamp(0, k - 1)  # (B, N, 2) sub-cell
    _scatter_cells(hits, sub, keep, 0, torch.ones_like(points[..., 2]))


def map_layers(state: torch.Tensor, min_hits: float = 1.0) -> dict[str, torch.Tensor]:
    """Derived layers of an evidence map ``state`` (B, 4, H, W).

    Returns:
        dict of (B, H, W) tensors: ``occupied`` (bool; obstacle evidence wins over free),
        ``explored`` (bool), ``free`` (bool), ``goal`` (float mean goal likelihood in [0, 1]).
    """
    occupied = state[:, OCC_HITS] >= min_hits  # (B, H, W)
    explored = occupied | (state[:, FREE_HITS] > 0) | (state[:, POINT_HITS] > 0)  # (B, H, W)
    goal = state[:, GOAL_SUM] / state[:, POINT_HITS].clamp_min(1.0)  # (B, H, W)
    return {"occupied": occupied, "explored": explored, "free": explored & ~occupied, "goal": goal}


def forget_noise(state: torch.Tensor, max_hits: float, free_ratio: float) -> None:
    """Zero the obstacle hits of the cells of ``state`` (4, H, W) that hold at most
    ``max_hits`` of them and at least ``free_ratio`` times as many free-space hits (grazing
    points of a door jamb), in place."""
    occ, free = state[OCC_HITS], state[FREE_HITS]  # (H, W) each, views
    noise = (occ > 0) & (occ <= max_hits) & (free >= free_ratio * occ)  # (H, W)
    occ[noise] = 0.0


def mark_unseen_free(state: torch.Tensor, cells: torch.Tensor) -> None:
    """One free-space hit to each of ``cells`` (D, 2) as (row, col) that holds no evidence
    yet in ``state`` (4, H, W), in place; cells seen before (obstacles too) are left alone."""
    seen = (state[:, cells[:, 0], cells[:, 1]] > 0).any(dim=0)  # (D,)
    cells = cells[~seen]  # (D', 2)
    state[FREE_HITS, cells[:, 0], cells[:, 1]] += 1.0
