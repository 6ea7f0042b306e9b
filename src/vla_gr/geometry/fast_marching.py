"""Geodesic (travel-time) distance on a grid by fast marching (scikit-fmm)."""

from __future__ import annotations

import sys

import numpy as np
import skfmm


def _to_numpy(x) -> tuple[np.ndarray, object]:
    """Return (numpy array, torch template or None) so results go back as the input kind.

    torch is only consulted when already imported (a tensor cannot exist otherwise), so
    numpy-only callers such as the simulator's workers never pay for importing it.
    """
    torch = sys.modules.get("torch")
    if torch is not None and isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy(), x
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


def upwind_gradient(travel: np.ndarray, cell_size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Upwind gradient (dT/dx, dT/dy), each (H, W), of a travel-time field ``travel`` (H, W).

    Along each axis the difference is taken towards the smaller neighbour when that neighbour
    is smaller than the cell itself (the eikonal upwind scheme), else it is 0. Infinite
    (blocked) neighbours are never used, so the result is finite wherever ``travel`` is;
    it is 0 on infinite cells. Axis convention as ``GridSpec``: x along columns, y along rows.
    """
    T = np.asarray(travel, dtype=np.float64)
    if T.ndim != 2:
        raise ValueError(f"travel must be (H, W), got shape {T.shape}")
    padded = np.pad(T, 1, constant_values=np.inf)  # (H + 2, W + 2)
    grads = []
    for lo, hi in (
        (padded[1:-1, :-2], padded[1:-1, 2:]),  # left / right neighbours -> d/dx
        (padded[:-2, 1:-1], padded[2:, 1:-1]),  # down / up neighbours -> d/dy
    ):
        use_lo = (lo <= hi) & (lo < T)
        use_hi = (hi < lo) & (hi < T)
        with np.errstate(invalid="ignore"):
            g = np.where(use_lo, T - lo, 0.0) + np.where(use_hi, hi - T, 0.0)
        g = np.where(np.isfinite(T) & np.isfinite(g), g, 0.0) / cell_size
        grads.append(g)
    return grads[0], grads[1]


def _corners(finite: np.ndarray, fr: float, fc: float) -> list[tuple[int, int, float]]:
    """The (row, col, weight) of the finite corners with weight > 0 of bilinear interpolation
    at fractional cell-centre (row, col) on a grid of ``finite`` (H, W)'s shape."""
    H, W = finite.shape
    fr = min(max(fr, 0.0), H - 1.0)
    fc = min(max(fc, 0.0), W - 1.0)
    r0, c0 = min(int(fr), H - 2) if H > 1 else 0, min(int(fc), W - 2) if W > 1 else 0
    ar, ac = fr - r0, fc - c0
    out = []
    for dr, wr in ((0, 1.0 - ar), (1, ar)):
        for dc, wc in ((0, 1.0 - ac), (1, ac)):
            r, c = min(r0 + dr, H - 1), min(c0 + dc, W - 1)
            w = wr * wc
            if finite[r, c] and w > 0:
                out.append((r, c, w))
    return out


def _interpolate(field: np.ndarray, corners: list[tuple[int, int, float]]) -> float:
    """``field`` (H, W) at the point of :func:`_corners`: the weighted mean of its corners."""
    total, weight = 0.0, 0.0
    for r, c, w in corners:
        total += w * field[r, c]
        weight += w
    return total / weight if weight > 0 else np.inf


def _bilinear(field: np.ndarray, finite: np.ndarray, fr: float, fc: float) -> float:
    """Bilinear ``field`` (H, W) at fractional cell-centre (row, col), over finite corners."""
    return _interpolate(field, _corners(finite, fr, fc))


def extract_path(
    travel,
    start,
    cell_size: float = 1.0,
    step: float = 0.5,
    max_length: float = np.inf,
    max_steps: int | None = None,
    gradient: tuple[np.ndarray, np.ndarray] | None = None,
):
    """Descend a travel-time field from ``start`` to its source with sub-cell steps.

    Steps of ``step`` cells follow the bilinearly interpolated upwind gradient of ``travel``;
    where that gradient vanishes or does not decrease T (saddles, obstacle corners) the path
    moves towards the lowest of the 8 neighbouring cells instead.

    Args:
        travel: (H, W) travel time (numpy or torch) from :func:`geodesic_distance`.
        start: (2,) metric (x, y) measured from the grid's lower-left corner.
        cell_size: metres per cell.
        step: step length in cells (0 < step <= 1).
        max_length: stop after this many metres.
        max_steps: hard cap on steps (default 4 * (H + W) / step).
        gradient: optional precomputed (dT/dx, dT/dy), each (H, W), e.g. from
            :func:`upwind_gradient`; only its direction is used.

    Returns:
        waypoints (N, 2) metric (x, y), same kind as ``travel``, starting at ``start`` and
        ending in a source cell (T = 0) or after ``max_length``. Empty (0, 2) when ``start`` is
        unreachable (T = inf) or outside the grid.
    """
    T, template = _to_numpy(travel)
    T = T.astype(np.float64)
    if T.ndim != 2:
        raise ValueError(f"travel must be (H, W), got shape {T.shape}")
    if not 0.0 < step <= 1.0:
        raise ValueError(f"step must be in (0, 1] cells, got {step}")
    H, W = T.shape
    x, y = (float(v) for v in np.asarray(_to_numpy(start)[0], dtype=np.float64).reshape(2))
    fc, fr = x / cell_size - 0.5, y / cell_size - 0.5  # fractional cell-centre coordinates
    finite = np.isfinite(T)
    path: list[tuple[float, float]] = []
    r, c = int(np.floor(fr + 0.5)), int(np.floor(fc + 0.5))
    if 0 <= r < H and 0 <= c < W and finite[r, c]:
        gx, gy = upwind_gradient(T, 1.0) if gradient is None else gradient
        path.append((fc, fr))
        cap = max_steps if max_steps is not None else int(4 * (H + W) / step)
        length = 0.0
        for _ in range(cap):
            if T[r, c] == 0.0 or length >= max_length:
                break
            corners = _corners(finite, fr, fc)  # shared by T and its gradient here
            here = _interpolate(T, corners)
            vx, vy = _interpolate(gx, corners), _interpolate(gy, corners)
            norm = float(np.hypot(vx, vy))
            moved = False
            if np.isfinite(norm) and norm > 1e-12:
                nc, nr = fc - step * vx / norm, fr - step * vy / norm
                ir, ic = int(np.floor(nr + 0.5)), int(np.floor(nc + 0.5))
                if (
                    0 <= ir < H
                    and 0 <= ic < W
                    and finite[ir, ic]
                    and _bilinear(T, finite, nr, nc) < here
                ):
                    fr, fc, moved = nr, nc, True
            if not moved:  # towards the lowest neighbouring cell
                window = T[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2]
                wr, wc = np.unravel_index(np.argmin(window), window.shape)
                tr, tc = max(r - 1, 0) + wr, max(c - 1, 0) + wc
                if T[tr, tc] >= T[r, c]:
                    if (tr, tc) == (r, c) and (abs(fr - r) > 1e-9 or abs(fc - c) > 1e-9):
                        tr, tc = r, c  # settle on the current (lowest) cell's centre
                    else:
                        break  # a local minimum that is not a source: give up
                d = float(np.hypot(tr - fr, tc - fc))
                frac = min(1.0, step / d) if d > 0 else 1.0
                fr, fc = fr + frac * (tr - fr), fc + frac * (tc - fc)
            length += float(np.hypot(fc - path[-1][0], fr - path[-1][1])) * cell_size
            path.append((fc, fr))
            r, c = int(np.floor(fr + 0.5)), int(np.floor(fc + 0.5))
    cells = np.asarray(path, dtype=np.float64).reshape(-1, 2)  # (N, 2) as (col, row)
    waypoints = (cells + 0.5) * cell_size  # (N, 2) metric (x, y)
    if template is not None:
        import torch

        return torch.as_tensor(waypoints, dtype=torch.float32, device=template.device)
    return waypoints
