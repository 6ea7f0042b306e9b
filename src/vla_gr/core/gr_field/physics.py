"""Pure maths of the GR field: masses, the Poisson potential, the conformal metric, geodesics.

All fields live on a regular grid with square cells of side ``cell_size`` metres, laid out as
``vla_gr.geometry.GridSpec``: array axis -2 (rows) runs along +y, axis -1 (cols) along +x.
Continuous positions are metric ``(x, y)`` measured from the grid's lower-left corner, so the
centre of cell ``(r, c)`` is ``((c + 0.5) * h, (r + 0.5) * h)``. Vector index 0 is x, 1 is y.

Every function is batched over a leading ``B`` and differentiable in torch unless stated.

Next in the data flow: :mod:`vla_gr.core.gr_field.planning` (``GRField`` composes it).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage

#: Mean of ln(r) over a square of side 1 centred on the origin: ln(1/2) + (ln 2 - 3 + pi/2) / 2.
LOG_R_UNIT_SQUARE_MEAN = math.log(0.5) + 0.5 * (math.log(2.0) - 3.0 + math.pi / 2.0)

_KERNEL_CACHE: dict[tuple, torch.Tensor] = {}


# --------------------------------------------------------------------------- masses


def frontier_mask(explored: torch.Tensor, occupied: torch.Tensor) -> torch.Tensor:
    """Frontier cells: explored, not occupied, with an unexplored 8-neighbour.

    Args:
        explored: (B, H, W) bool.
        occupied: (B, H, W) bool.

    Returns:
        (B, H, W) bool. Cells outside the grid do not count as unexplored.

    Computed on the bounding box of the explored cells grown by one cell (no frontier lies
    outside it, and every neighbour of an explored cell lies in it), so the answer equals
    the full-grid one.
    """
    out = torch.zeros_like(explored)  # (B, H, W)
    box = bounding_box(explored, 1)
    if box is None:
        return out
    seen, occ = explored[:, box[0], box[1]], occupied[:, box[0], box[1]]  # (B, h, w) the box
    out[:, box[0], box[1]] = seen & ~occ & dilate_square(~seen, 1)
    return out


def bounding_box(mask: torch.Tensor, margin: int) -> tuple[slice, slice] | None:
    """(rows, cols) slices of the box holding every True cell of ``mask`` (B, H, W) in any
    map, grown by ``margin`` cells and clipped to the grid; None when no cell is True."""
    rows = mask.any(dim=(0, 2)).nonzero().flatten()  # (R,) rows holding a True cell
    if len(rows) == 0:
        return None
    cols = mask.any(dim=(0, 1)).nonzero().flatten()  # (C,)
    H, W = mask.shape[-2:]
    return (
        slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + margin + 1, H)),
        slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + margin + 1, W)),
    )


def dilate_square(mask: torch.Tensor, k: int) -> torch.Tensor:
    """Cells (B, H, W) bool within a (2k+1) x (2k+1) square of a True cell of ``mask`` (B, H, W).

    Two separable 1-D max-pools (cheaper than one square pool); the border is not True.
    """
    if k < 0:
        raise ValueError(f"k must be >= 0, got {k}")
    x = mask.to(torch.float32)[:, None]  # (B, 1, H, W)
    x = F.max_pool2d(x, (1, 2 * k + 1), stride=1, padding=(0, k))  # (B, 1, H, W)
    x = F.max_pool2d(x, (2 * k + 1, 1), stride=1, padding=(k, 0))  # (B, 1, H, W)
    return x[:, 0] > 0


def grow_through(seed: torch.Tensor, passable: torch.Tensor, steps: int) -> torch.Tensor:
    """Cells (B, H, W) bool reached from ``seed`` in at most ``steps`` 8-neighbour moves, each
    onto a ``passable`` cell: ``steps`` rounds of ``dilate_square(., 1) & passable``.

    Computed on the bounding box of all seeds grown by ``steps + 1`` cells, which no move can
    leave, so the answer equals the full-grid rounds; no seed returns ``seed`` unchanged.
    """
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    box = bounding_box(seed, steps + 1) if steps > 0 else None
    if box is None:
        return seed.clone()
    r, c = box
    grown, ok = seed[:, r, c], passable[:, r, c]  # (B, h, w) the box
    for _ in range(steps):
        grown = dilate_square(grown, 1) & ok  # (B, h, w)
    out = seed.clone()  # (B, H, W)
    out[:, r, c] = grown
    return out


def normalise_mass(weights: torch.Tensor, total: float | torch.Tensor, cell_size: float):
    """Density (B, H, W) proportional to ``weights`` (B, H, W) with integral ``total``.

    ``sum(rho) * cell_size**2 == total`` per batch element; all-zero weights give zero density.
    """
    if cell_size <= 0:
        raise ValueError(f"cell_size must be > 0, got {cell_size}")
    weights = weights.clamp_min(0)  # (B, H, W)
    norm = weights.sum(dim=(-2, -1), keepdim=True)  # (B, 1, 1)
    scale = torch.where(norm > 0, total / (norm.clamp_min(1e-12) * cell_size**2), 0.0)
    return weights * scale  # (B, H, W)


def obstacle_proximity(occupied: torch.Tensor, cell_size: float, length: float) -> torch.Tensor:
    """exp(-d / length) with d the distance (m) to the nearest occupied cell centre.

    Args:
        occupied: (B, H, W) bool (not differentiable: an exact distance transform per map).

    Returns:
        (B, H, W) float in [0, 1]; 1 on obstacles, 0 everywhere when a map has none.
    """
    if length <= 0:
        raise ValueError(f"length must be > 0, got {length}")
    occ = occupied.detach().cpu().numpy().astype(bool)  # (B, H, W)
    out = np.zeros(occ.shape, np.float32)
    for b in range(occ.shape[0]):
        if occ[b].any():
            dist = ndimage.distance_transform_edt(~occ[b]) * cell_size  # (H, W)
            out[b] = np.exp(-dist / length)
    return torch.from_numpy(out).to(occupied.device)


# --------------------------------------------------------------------------- Poisson


def green_kernel_2d(H: int, W: int, cell_size: float, G: float = 1.0) -> torch.Tensor:
    """Free-space 2-D Green's function 2 G ln r on the (2H, 2W) periodic padding grid.

    Offsets are wrapped (index i means dy = min(i, 2H - i) cells) so that a circular
    convolution of a zero-padded density equals the linear (isolated) convolution. The r = 0
    entry holds the cell average of 2 G ln r over the source cell.

    Returns:
        (2H, 2W) float64.
    """
    iy = torch.arange(2 * H, dtype=torch.float64)
    ix = torch.arange(2 * W, dtype=torch.float64)
    dy = torch.minimum(iy, 2 * H - iy) * cell_size  # (2H,)
    dx = torch.minimum(ix, 2 * W - ix) * cell_size  # (2W,)
    r = torch.sqrt(dy[:, None] ** 2 + dx[None, :] ** 2)  # (2H, 2W)
    r[0, 0] = 1.0
    kernel = 2.0 * G * torch.log(r)  # (2H, 2W)
    kernel[0, 0] = 2.0 * G * (math.log(cell_size) + LOG_R_UNIT_SQUARE_MEAN)
    return kernel


def _kernel_fft(H: int, W: int, cell_size: float, G: float, dtype, device) -> torch.Tensor:
    key = (H, W, float(cell_size), float(G), dtype, str(device))
    if key not in _KERNEL_CACHE:
        if len(_KERNEL_CACHE) > 16:
            _KERNEL_CACHE.clear()
        kernel = green_kernel_2d(H, W, cell_size, G) * cell_size**2  # (2H, 2W)
        _KERNEL_CACHE[key] = torch.fft.rfft2(kernel.to(device=device, dtype=dtype))
    return _KERNEL_CACHE[key]


def solve_poisson(rho: torch.Tensor, cell_size: float, G: float = 1.0) -> torch.Tensor:
    """Potential phi with laplacian(phi) = 4 pi G rho and free-space boundary conditions.

    The solution is the convolution of the density with the Green's function 2 G ln r,
    done as a zero-padded FFT convolution (Hockney's method), so masses near the border do
    not see periodic images. Differentiable with respect to ``rho``.

    Args:
        rho: (B, H, W) or (H, W) surface density (mass per square metre).
        cell_size: metres per cell.
        G: gravitational constant.

    Returns:
        phi with the same shape and dtype as ``rho``.
    """
    if cell_size <= 0:
        raise ValueError(f"cell_size must be > 0, got {cell_size}")
    squeeze = rho.ndim == 2
    if squeeze:
        rho = rho[None]
    if rho.ndim != 3:
        raise ValueError(f"rho must be (B, H, W) or (H, W), got {tuple(rho.shape)}")
    H, W = rho.shape[-2:]
    work = rho if rho.dtype in (torch.float32, torch.float64) else rho.float()
    k_hat = _kernel_fft(H, W, cell_size, G, work.dtype, work.device)  # (2H, W + 1)
    rho_hat = torch.fft.rfft2(work, s=(2 * H, 2 * W))  # (B, 2H, W + 1)
    phi = torch.fft.irfft2(rho_hat * k_hat, s=(2 * H, 2 * W))[..., :H, :W]  # (B, H, W)
    phi = phi.to(rho.dtype)
    return phi[0] if squeeze else phi


# --------------------------------------------------------------------------- metric


def conformal_log_factor(
    phi: torch.Tensor, proximity: torch.Tensor, beta: float, kappa: float
) -> torch.Tensor:
    """psi (B, H, W) of the metric g = exp(2 psi) delta.

    psi = beta * phi_hat + kappa * proximity, with phi_hat the potential rescaled to [0, 1]
    per map: low where the attracting masses pull (wells of phi), high near obstacles.

    Args:
        phi: (B, H, W) potential.
        proximity: (B, H, W) obstacle proximity in [0, 1] (see :func:`obstacle_proximity`).
    """
    lo = phi.amin(dim=(-2, -1), keepdim=True)  # (B, 1, 1)
    hi = phi.amax(dim=(-2, -1), keepdim=True)  # (B, 1, 1)
    phi_hat = (phi - lo) / (hi - lo).clamp_min(1e-9)  # (B, H, W)
    return beta * phi_hat + kappa * proximity  # (B, H, W)


def grid_gradient(field: torch.Tensor, cell_size: float) -> torch.Tensor:
    """Central-difference gradient (one-sided, 2nd order at edges) as (B, 2, H, W) = (d/dx, d/dy).

    Args:
        field: (B, H, W) with H, W >= 3.
    """
    if min(field.shape[-2:]) < 3:
        raise ValueError(f"field must be at least 3 x 3, got {tuple(field.shape)}")
    return torch.stack([_diff(field, -1, cell_size), _diff(field, -2, cell_size)], dim=1)


def _diff(f: torch.Tensor, dim: int, h: float) -> torch.Tensor:
    """Derivative along ``dim``: central inside, one-sided 2nd order at the ends.

    Written with differences of neighbours only, so a constant field gives exactly 0.
    """
    d = f.diff(dim=dim)  # forward differences, one shorter along dim
    n = d.shape[dim]
    first = 1.5 * d.narrow(dim, 0, 1) - 0.5 * d.narrow(dim, 1, 1)
    last = 1.5 * d.narrow(dim, n - 1, 1) - 0.5 * d.narrow(dim, n - 2, 1)
    inner = 0.5 * (d.narrow(dim, 0, n - 1) + d.narrow(dim, 1, n - 1))
    return torch.cat([first, inner, last], dim=dim) / h


def christoffel_conformal(psi: torch.Tensor, cell_size: float) -> torch.Tensor:
    """Christoffel symbols of g = exp(2 psi) delta in 2-D.

    Gamma^k_ij = delta^k_i d_j psi + delta^k_j d_i psi - delta_ij d_k psi.

    Args:
        psi: (B, H, W) log conformal factor.

    Returns:
        (B, 2, 2, 2, H, W) with index order [b, k, i, j]; index 0 is x (columns), 1 is y (rows).
    """
    if psi.ndim != 3:
        raise ValueError(f"psi must be (B, H, W), got {tuple(psi.shape)}")
    d = grid_gradient(psi, cell_size)  # (B, 2, H, W)
    eye = torch.eye(2, dtype=psi.dtype, device=psi.device)  # (2, 2)
    t1 = torch.einsum("ki,bjhw->bkijhw", eye, d)  # (B, 2, 2, 2, H, W)
    t2 = torch.einsum("kj,bihw->bkijhw", eye, d)  # (B, 2, 2, 2, H, W)
    t3 = torch.einsum("ij,bkhw->bkijhw", eye, d)  # (B, 2, 2, 2, H, W)
    return t1 + t2 - t3


def christoffel_from_metric(g: torch.Tensor, cell_size: float) -> torch.Tensor:
    """Christoffel symbols of a general metric by finite differences (reference formula).

    Gamma^k_ij = 1/2 g^kl (d_i g_lj + d_j g_li - d_l g_ij).

    Args:
        g: (B, 2, 2, H, W) symmetric positive-definite metric.

    Returns:
        (B, 2, 2, 2, H, W) indexed [b, k, i, j].
    """
    B, _, _, H, W = g.shape
    flat = g.reshape(B * 4, H, W)  # (4B, H, W)
    dg = grid_gradient(flat, cell_size).reshape(B, 2, 2, 2, H, W)  # [b, l, j, d]: d_d g_lj
    dg = dg.permute(0, 3, 1, 2, 4, 5)  # (B, 2, 2, 2, H, W) as [b, d, l, j]
    g_inv = torch.linalg.inv(g.permute(0, 3, 4, 1, 2)).permute(0, 3, 4, 1, 2)  # (B, 2, 2, H, W)
    # lower[b, l, i, j] = d_i g_lj + d_j g_li - d_l g_ij
    lower = (
        dg.permute(0, 2, 1, 3, 4, 5)  # [b, l, i, j] = d_i g_lj
        + dg.permute(0, 2, 3, 1, 4, 5)  # [b, l, i, j] = d_j g_li
        - dg  # [b, l, i, j] = d_l g_ij
    )
    return 0.5 * torch.einsum("bklhw,blijhw->bkijhw", g_inv, lower)


# --------------------------------------------------------------------------- sampling / RK4


def sample_bilinear(field: torch.Tensor, xy: torch.Tensor, cell_size: float) -> torch.Tensor:
    """Bilinear values of ``field`` (B, C, H, W) at metric points ``xy`` (B, N, 2) -> (B, N, C).

    Points outside the grid take the border value; a field with B = 1 is shared by all points.
    """
    H, W = field.shape[-2:]
    if field.shape[0] == 1 and xy.shape[0] > 1:
        field = field.expand(xy.shape[0], *field.shape[1:])  # share one field across the batch
    gx = 2.0 * xy[..., 0] / (W * cell_size) - 1.0  # (B, N)
    gy = 2.0 * xy[..., 1] / (H * cell_size) - 1.0  # (B, N)
    grid = torch.stack([gx, gy], dim=-1)[:, :, None, :].to(field.dtype)  # (B, N, 1, 2)
    out = F.grid_sample(field, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out[..., 0].transpose(1, 2)  # (B, N, C)


def geodesic_acceleration(gamma: torch.Tensor, x: torch.Tensor, v: torch.Tensor, cell_size: float):
    """x'' = -Gamma^k_ij(x) v^i v^j.

    Args:
        gamma: (B, 2, 2, 2, H, W) Christoffel symbols (B = 1 is shared by all points).
        x: (B, 2) metric positions; v: (B, 2) velocities.

    Returns:
        (B, 2) acceleration.
    """
    flat = gamma.reshape(gamma.shape[0], 8, *gamma.shape[-2:])  # (B, 8, H, W)
    g_at = sample_bilinear(flat, x[:, None, :], cell_size)[:, 0]  # (B, 8)
    g_at = g_at.reshape(x.shape[0], 2, 2, 2)  # (B, 2, 2, 2)
    return -torch.einsum("bkij,bi,bj->bk", g_at, v, v)  # (B, 2)


def integrate_geodesic(
    gamma: torch.Tensor,
    x0: torch.Tensor,
    v0: torch.Tensor,
    steps: int,
    dt: float,
    cell_size: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Integrate the geodesic equation x'' = -Gamma(x)(x', x') with classical RK4.

    Gamma is interpolated bilinearly between cell centres.

    Args:
        gamma: (B, 2, 2, 2, H, W) Christoffel symbols, index [b, k, i, j].
        x0: (B, 2) start positions (metric, from the grid's lower-left corner).
        v0: (B, 2) start velocities.
        steps: number of RK4 steps (>= 1).
        dt: affine-parameter step.
        cell_size: metres per cell of ``gamma``'s grid (use the value ``gamma`` was computed
            with; positions are then in metres).

    Returns:
        positions (B, steps + 1, 2) and velocities (B, steps + 1, 2).
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    if dt <= 0:
        raise ValueError(f"dt must be > 0, got {dt}")
    if gamma.ndim != 6 or gamma.shape[1:4] != (2, 2, 2):
        raise ValueError(f"gamma must be (B, 2, 2, 2, H, W), got {tuple(gamma.shape)}")
    x, v = x0.to(gamma.dtype), v0.to(gamma.dtype)  # (B, 2)
    xs, vs = [x], [v]

    def acc(p, q):
        return geodesic_acceleration(gamma, p, q, cell_size)

    for _ in range(steps):
        k1x, k1v = v, acc(x, v)
        k2x, k2v = v + 0.5 * dt * k1v, acc(x + 0.5 * dt * k1x, v + 0.5 * dt * k1v)
        k3x, k3v = v + 0.5 * dt * k2v, acc(x + 0.5 * dt * k2x, v + 0.5 * dt * k2v)
        k4x, k4v = v + dt * k3v, acc(x + dt * k3x, v + dt * k3v)
        x = x + dt / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)  # (B, 2)
        v = v + dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)  # (B, 2)
        xs.append(x)
        vs.append(v)
    return torch.stack(xs, dim=1), torch.stack(vs, dim=1)  # (B, steps + 1, 2) each


def conformal_speed_squared(
    psi: torch.Tensor, xs: torch.Tensor, vs: torch.Tensor, cell_size: float
) -> torch.Tensor:
    """g(x', x') = exp(2 psi(x)) |x'|^2 along a path.

    Args:
        psi: (B, H, W); xs, vs: (B, N, 2).

    Returns:
        (B, N).
    """
    psi_at = sample_bilinear(psi[:, None], xs, cell_size)[..., 0]  # (B, N)
    return torch.exp(2.0 * psi_at) * (vs**2).sum(-1)  # (B, N)
