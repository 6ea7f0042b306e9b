"""Field maths against analytic answers: Poisson, Christoffel symbols, RK4 geodesics, paths."""

import math

import numpy as np
import pytest
import torch

from vla_gr.core.gr_field.physics import (
    LOG_R_UNIT_SQUARE_MEAN,
    christoffel_conformal,
    christoffel_from_metric,
    conformal_speed_squared,
    dilate_square,
    frontier_mask,
    green_kernel_2d,
    grid_gradient,
    grow_through,
    integrate_geodesic,
    normalise_mass,
    obstacle_proximity,
    sample_bilinear,
    solve_poisson,
)
from vla_gr.geometry import extract_path, geodesic_distance

H = 0.05  # cell size (m)


def point_mass(n: int, r: int, c: int, m: float) -> torch.Tensor:
    rho = torch.zeros(1, n, n, dtype=torch.float64)
    rho[0, r, c] = m / H**2  # (1, n, n) density of a mass m in one cell
    return rho


# --------------------------------------------------------------------------- Poisson


def test_log_r_cell_average_constant():
    xs = (np.arange(2000) + 0.5) / 2000 - 0.5
    X, Y = np.meshgrid(xs, xs)
    assert pytest.approx(np.log(np.hypot(X, Y)).mean(), abs=1e-4) == LOG_R_UNIT_SQUARE_MEAN


@pytest.mark.parametrize("G,m", [(1.0, 1.0), (0.5, 3.0)])
def test_point_mass_potential_differences_are_2gm_log_ratio(G, m):
    # source near a corner: periodic images (no zero padding) would break this badly
    n, r0, c0 = 96, 10, 12
    phi = solve_poisson(point_mass(n, r0, c0, m), H, G)[0]  # (n, n)
    for dr, dc, k in [(0, 1, 5), (1, 0, 7), (1, 1, 3)]:
        for k1, k2 in [(k, 8 * k), (2 * k, 10 * k)]:
            p1 = phi[r0 + dr * k1, c0 + dc * k1]
            p2 = phi[r0 + dr * k2, c0 + dc * k2]
            r1, r2 = math.hypot(dr, dc) * k1, math.hypot(dr, dc) * k2
            expected = 2 * G * m * math.log(r2 / r1)
            assert float(p2 - p1) == pytest.approx(expected, rel=0.02)


def test_flux_through_circle_is_4_pi_g_m():
    n, m, G = 128, 2.5, 0.7
    phi = solve_poisson(point_mass(n, 64, 64, m), H, G)  # (1, n, n)
    grad = grid_gradient(phi, H)  # (1, 2, n, n)
    centre = (64 + 0.5) * H
    for R in (0.8, 1.6, 2.4):
        theta = torch.linspace(0, 2 * math.pi, 721, dtype=torch.float64)[:-1]
        normal = torch.stack([torch.cos(theta), torch.sin(theta)], dim=-1)  # (M, 2)
        pts = (centre + R * normal)[None]  # (1, M, 2)
        g_at = sample_bilinear(grad, pts, H)[0]  # (M, 2)
        flux = float((g_at * normal).sum(-1).mean() * 2 * math.pi * R)
        assert flux == pytest.approx(4 * math.pi * G * m, rel=0.01)


def test_poisson_matches_brute_force_sum_and_is_differentiable():
    gen = torch.Generator().manual_seed(0)
    rho = torch.rand(2, 7, 9, dtype=torch.float64, generator=gen).requires_grad_(True)
    phi = solve_poisson(rho, 0.3, G=1.3)  # (2, 7, 9)
    ys, xs = torch.meshgrid(torch.arange(7.0), torch.arange(9.0), indexing="ij")
    pos = torch.stack([xs.flatten(), ys.flatten()], -1).double() * 0.3  # (63, 2)
    dist = torch.cdist(pos, pos)  # (63, 63)
    kernel = 2 * 1.3 * torch.log(dist.fill_diagonal_(1.0))
    kernel.fill_diagonal_(2 * 1.3 * (math.log(0.3) + LOG_R_UNIT_SQUARE_MEAN))
    direct = (rho.detach().reshape(2, -1) @ kernel.T * 0.3**2).reshape(2, 7, 9)
    torch.testing.assert_close(phi.detach(), direct, rtol=1e-9, atol=1e-9)
    phi[0, 3, 4].backward()
    torch.testing.assert_close(rho.grad[0].flatten(), kernel[3 * 9 + 4] * 0.3**2)
    assert torch.all(rho.grad[1] == 0)


def test_poisson_validation_and_unbatched():
    with pytest.raises(ValueError, match="cell_size"):
        solve_poisson(torch.zeros(4, 4), 0.0)
    with pytest.raises(ValueError, match="rho"):
        solve_poisson(torch.zeros(4), 0.1)
    assert solve_poisson(torch.zeros(5, 6), 0.1).shape == (5, 6)
    k = green_kernel_2d(3, 4, 0.5)
    assert k.shape == (6, 8)  # wrapped offsets: k[i, j] == k[-i, -j]
    assert torch.equal(k, k.flip(0).roll(1, 0)) and torch.equal(k, k.flip(1).roll(1, 1))
    assert float(k[0, 1]) == pytest.approx(2 * math.log(0.5))


# --------------------------------------------------------------------------- masses


@pytest.mark.parametrize("seed", range(6))
def test_the_frontier_on_the_explored_box_equals_the_full_grid_definition(seed):
    # explored patches anywhere, touching the border too, in a batch of two maps
    g = torch.Generator().manual_seed(seed)
    explored = torch.zeros(2, 24, 20, dtype=torch.bool)
    for b in range(2):
        for _ in range(3):
            r, c = (int(v) for v in torch.randint(0, 20, (2,), generator=g))
            explored[b, r : r + 6, max(c - 2, 0) : c + 5] = True
    occupied = explored & (torch.rand(explored.shape, generator=g) < 0.2)
    full = explored & ~occupied & dilate_square(~explored, 1)  # the definition, whole grid
    assert torch.equal(frontier_mask(explored, occupied), full)
    none = torch.zeros(1, 5, 5, dtype=torch.bool)
    assert not frontier_mask(none, none).any()


def test_frontier_mass_and_proximity():
    explored = torch.zeros(1, 6, 6, dtype=torch.bool)
    explored[0, 1:5, 1:4] = True
    occupied = torch.zeros_like(explored)
    occupied[0, 1, 1] = True
    front = frontier_mask(explored, occupied)[0]
    expected = explored[0] & ~occupied[0]
    expected[2:4, 2] = False  # interior cells have no unexplored neighbour
    assert torch.equal(front, expected)
    rho = normalise_mass(front[None].float(), 2.0, 0.1)
    assert float(rho.sum() * 0.1**2) == pytest.approx(2.0)
    assert torch.all(normalise_mass(torch.zeros(1, 3, 3), 1.0, 0.1) == 0)
    prox = obstacle_proximity(occupied, 0.1, 0.3)[0]
    assert prox[1, 1] == 1 and float(prox[1, 4]) == pytest.approx(math.exp(-0.3 / 0.3))
    assert torch.all(obstacle_proximity(torch.zeros(1, 3, 3, dtype=torch.bool), 0.1, 0.3) == 0)


@pytest.mark.parametrize("steps", [0, 1, 3, 6])
def test_grow_through_equals_full_grid_rounds(steps):
    gen = torch.Generator().manual_seed(steps)
    passable = torch.rand(3, 24, 20, generator=gen) > 0.3  # (B, H, W)
    seed = torch.zeros(3, 24, 20, dtype=torch.bool)
    seed[0, 0, 19] = True  # at a corner: the box is clipped by the grid
    seed[1, 12, 3] = seed[1, 14, 9] = True
    # map 2 has no seed of its own but shares the box of the others
    expected = seed.clone()
    for _ in range(steps):
        expected = dilate_square(expected, 1) & passable
    grown = grow_through(seed, passable, steps)
    assert torch.equal(grown, expected)
    assert not grown[2].any()
    if steps >= 2:  # a move onto an impassable cell stops the growth there
        wall = torch.ones(1, 9, 9, dtype=torch.bool)
        wall[0, :, 4] = False
        one = torch.zeros(1, 9, 9, dtype=torch.bool)
        one[0, 4, 2] = True
        assert not grow_through(one, wall, steps)[0, :, 5:].any()
    nothing = torch.zeros(2, 5, 5, dtype=torch.bool)
    assert torch.equal(grow_through(nothing, passable[:2, :5, :5], steps), nothing)
    with pytest.raises(ValueError, match="steps"):
        grow_through(seed, passable, -1)


# --------------------------------------------------------------------------- metric


def smooth_psi(n: int, h: float) -> tuple[torch.Tensor, torch.Tensor]:
    """psi = 0.4 sin(x) cos(0.7 y) + 0.2 x on an n x n grid, and its analytic gradient."""
    c = (torch.arange(n, dtype=torch.float64) + 0.5) * h
    Y, X = torch.meshgrid(c, c, indexing="ij")
    psi = 0.4 * torch.sin(X) * torch.cos(0.7 * Y) + 0.2 * X  # (n, n)
    dx = 0.4 * torch.cos(X) * torch.cos(0.7 * Y) + 0.2
    dy = -0.28 * torch.sin(X) * torch.sin(0.7 * Y)
    return psi[None], torch.stack([dx, dy])[None]  # (1, n, n), (1, 2, n, n)


def test_christoffel_of_constant_psi_is_zero():
    gamma = christoffel_conformal(torch.full((2, 9, 11), 0.7), 0.1)
    assert gamma.shape == (2, 2, 2, 2, 9, 11)
    assert torch.all(gamma == 0)


def test_christoffel_closed_form_matches_metric_finite_differences():
    n, h = 80, 0.05
    psi, dpsi = smooth_psi(n, h)
    gamma = christoffel_conformal(psi, h)  # (1, 2, 2, 2, n, n)
    g = torch.exp(2 * psi)[:, None, None] * torch.eye(2, dtype=psi.dtype)[None, :, :, None, None]
    reference = christoffel_from_metric(g, h)
    inner = (..., slice(2, -2), slice(2, -2))
    torch.testing.assert_close(gamma[inner], reference[inner], rtol=0, atol=2e-3)
    # hand-written components: Gamma^x_xx = dx psi, Gamma^x_yy = -dx psi, Gamma^y_xy = dx psi
    dx, dy = dpsi[0, 0], dpsi[0, 1]
    for (k, i, j), want in {
        (0, 0, 0): dx,
        (0, 1, 1): -dx,
        (0, 0, 1): dy,
        (1, 0, 1): dx,
        (1, 1, 1): dy,
        (1, 0, 0): -dy,
    }.items():
        torch.testing.assert_close(gamma[0, k, i, j][inner[1:]], want[inner[1:]], atol=2e-3, rtol=0)


def test_flat_metric_geodesic_is_a_straight_line():
    gamma = christoffel_conformal(torch.zeros(2, 20, 20, dtype=torch.float64), 0.1)
    x0 = torch.tensor([[0.5, 0.6], [1.0, 1.5]], dtype=torch.float64)
    v0 = torch.tensor([[1.0, 0.3], [-0.2, 0.1]], dtype=torch.float64)
    xs, vs = integrate_geodesic(gamma, x0, v0, steps=25, dt=0.04, cell_size=0.1)
    t = torch.arange(26, dtype=torch.float64)[None, :, None] * 0.04
    torch.testing.assert_close(xs, x0[:, None] + t * v0[:, None], rtol=0, atol=1e-12)
    torch.testing.assert_close(vs, v0[:, None].expand_as(vs), rtol=0, atol=1e-12)


def test_rk4_conserves_metric_speed_for_smooth_psi():
    n, h = 160, 0.025  # 4 m x 4 m
    psi, _ = smooth_psi(n, h)
    gamma = christoffel_conformal(psi, h)
    x0 = torch.tensor([[0.6, 0.8], [1.5, 3.0]], dtype=torch.float64)
    v0 = torch.tensor([[1.0, 0.5], [0.3, -1.0]], dtype=torch.float64)
    xs, vs = integrate_geodesic(gamma, x0, v0, steps=200, dt=0.01, cell_size=h)
    assert xs.shape == (2, 201, 2)
    speed2 = conformal_speed_squared(psi.expand(2, -1, -1), xs, vs, h)  # (2, 201)
    drift = (speed2 / speed2[:, :1] - 1).abs().max()
    assert float(drift) < 1e-3
    # the path really curves (psi is not flat), so the check above is not vacuous
    chord = xs[:, -1] - xs[:, 0]
    straight = x0 + 2.0 * v0 - xs[:, 0]
    assert float((chord - straight).norm(dim=-1).min()) > 0.05


def test_integrate_geodesic_validation():
    gamma = torch.zeros(1, 2, 2, 2, 4, 4)
    with pytest.raises(ValueError, match="steps"):
        integrate_geodesic(gamma, torch.zeros(1, 2), torch.ones(1, 2), 0, 0.1, 0.1)
    with pytest.raises(ValueError, match="gamma"):
        integrate_geodesic(torch.zeros(1, 2, 4, 4), torch.zeros(1, 2), torch.ones(1, 2), 1, 0.1, 1)


# --------------------------------------------------------------------------- paths


def test_path_through_door_follows_hand_computed_detour():
    rows, cols = 100, 200
    obs = np.zeros((rows, cols), bool)
    obs[:, 100] = True
    obs[80:90, 100] = False  # a door in the wall at column 100
    src = np.zeros((rows, cols), bool)
    src[20, 60] = True
    T = geodesic_distance(1.0, src, obs, H)  # (rows, cols)
    start = np.array([(140 + 0.5) * H, (20 + 0.5) * H])
    path = extract_path(T, start, H, step=0.5)  # (N, 2)
    edge = np.array([100.0, 80.0])  # the door edge the shortest path bends around (col, row)
    detour = (np.linalg.norm(edge - [60, 20]) + np.linalg.norm([140, 20] - edge)) * H
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    assert length == pytest.approx(detour, rel=0.03)
    assert np.allclose(path[0], start)
    end = np.floor(path[-1] / H).astype(int)
    assert T[end[1], end[0]] == 0
    crossing = np.argmin(np.abs(path[:, 0] - 100.5 * H))  # where it passes the wall column
    assert 80 * H <= path[crossing, 1] <= 90 * H
    cells = np.floor(path / H).astype(int)
    assert not obs[cells[:, 1], cells[:, 0]].any()


def test_path_is_straight_in_uniform_cost_and_respects_max_length():
    src = torch.zeros(60, 60, dtype=torch.bool)
    src[30, 50] = True
    T = geodesic_distance(torch.ones(60, 60), src, None, 0.1)
    path = extract_path(T, torch.tensor([1.05, 3.05]), 0.1, step=0.5)
    assert isinstance(path, torch.Tensor) and path.shape[1] == 2
    assert float((path[:, 1] - 3.05).abs().max()) < 0.06  # stays on the row of the source
    short = extract_path(T, torch.tensor([1.05, 3.05]), 0.1, step=0.5, max_length=1.0)
    seg = (short[1:] - short[:-1]).norm(dim=-1)
    assert 1.0 <= float(seg.sum()) < 1.0 + 0.051


def test_path_from_unreachable_start_is_empty():
    obs = np.zeros((20, 20), bool)
    obs[:, 10] = True
    src = np.zeros((20, 20), bool)
    src[5, 2] = True
    T = geodesic_distance(1.0, src, obs, 0.1)
    assert extract_path(T, np.array([1.55, 0.55]), 0.1).shape == (0, 2)
    assert extract_path(T, np.array([-5.0, 0.55]), 0.1).shape == (0, 2)


def test_path_with_precomputed_gradient_is_identical():
    from vla_gr.geometry import upwind_gradient

    src = np.zeros((40, 50), bool)
    src[5, 45] = True
    obs = np.zeros((40, 50), bool)
    obs[10:30, 20] = True
    T = geodesic_distance(1.0, src, obs, 0.1)
    start = np.array([0.55, 3.55])
    a = extract_path(T, start, 0.1)
    b = extract_path(T, start, 0.1, gradient=upwind_gradient(T, 0.1))
    np.testing.assert_allclose(a, b)


def test_geodesic_endpoint_is_differentiable_in_psi():
    psi, _ = smooth_psi(40, 0.1)
    psi = psi.clone().requires_grad_(True)
    gamma = christoffel_conformal(psi, 0.1)
    x0 = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    v0 = torch.tensor([[1.0, 0.2]], dtype=torch.float64)
    xs, _ = integrate_geodesic(gamma, x0, v0, steps=20, dt=0.05, cell_size=0.1)
    xs[0, -1, 1].backward()
    assert torch.isfinite(psi.grad).all() and psi.grad.abs().sum() > 0
