"""Geodesic (travel-time) distance on a grid by fast marching (scikit-fmm)."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import skfmm

ArrayLike = TypeVar("ArrayLike")


def _to_numpy(x) -> tuple[np.ndarray, object]:
    """Return (numpy array, torch template or None) so results go back as the input kind."""
    try:
        import torch

        if isinstance(x, torch.Tensor):
            return x.detach().cpu().numpy(), x
    except ImportError:  # pragma: no cover - torch is a hard dependency
        pass
    return np.asarray(x), None


def geodesic_distance(
    cost,
    sources,
    obstacles=None,
    cell_size: float = 1.0,
):
    """Travel time T (H, W) from the ``sources`` region through a field of local ``cost``.

    Solves the eikonal equation |grad T| = cost with fast marching (speed = 1 / cost), so with
    ``cost == 1`` T is the shortest-path length in metres around ``obstacles``.

    Args:
        cost: (H, W) positive cost per metre, or a scalar for uniform cost.
        sources: (H, W) bool, cells where T = 0 (e.g. the goal footprint).
        obstacles: (H, W) bool or None; these cells are impassable.
        cell_size: metres per cell.

    Returns:
        T (H, W) float, same kind (numpy/torch) as ``sources``. Source cells are 0; cells that
        cannot be reached (blocked, or no source) are ``inf``. The front starts at the boundary
        of the source region (half a cell outside source cell centres), the usual FMM convention.
    """
    src, template = _to_numpy(sources)
    src = src.astype(bool)
    shape = src.shape
    if src.ndim != 2:
        raise ValueError(f"sources must be (H, W), got shape {shape}")
    obs = np.zeros(shape, bool) if obstacles is None else _to_numpy(obstacles)[0].astype(bool)
    cost_np = _to_numpy(cost)[0].astype(np.float64)
    if cost_np.ndim == 0:
        cost_np = np.full(shape, float(cost_np))
    if cost_np.shape != shape or obs.shape != shape:
        raise ValueError(
            f"cost {cost_np.shape}, sources {shape} and obstacles {obs.shape} must match"
        )
    if not np.all(np.isfinite(cost_np[~obs])) or np.any(cost_np[~obs] <= 0):
        raise ValueError("cost must be finite and > 0 on free cells")

    travel = np.full(shape, np.inf)
    src_free = src & ~obs
    if src_free.any() and not src_free.all():
        phi = np.where(src_free, -0.5, 0.5)
        phi = np.ma.MaskedArray(phi, mask=obs)
        speed = 1.0 / np.where(obs, 1.0, cost_np)
        try:
            result = skfmm.travel_time(phi, speed, dx=cell_size)
        except ValueError:  # the source region touches no free neighbour
            result = np.ma.masked_all(shape)
        values = np.ma.filled(np.ma.asarray(result, dtype=np.float64), np.inf)
        travel = np.where(np.ma.getmaskarray(result) | obs, np.inf, np.abs(values))
    travel[src_free] = 0.0

    if template is not None:
        import torch

        return torch.as_tensor(
            travel,
            dtype=template.dtype if template.is_floating_point() else torch.float32,
            device=template.device,
        )
    return travel
