import numpy as np
import pytest
import torch

from vla_gr.geometry import geodesic_distance, inflate_obstacles

CELL = 0.05


def test_uniform_cost_is_euclidean_within_grid_error():
    src = np.zeros((121, 121), bool)
    src[60, 60] = True
    T = geodesic_distance(1.0, src, None, CELL)  # (H, W)
    rows, cols = np.mgrid[0:121, 0:121]
    euclid = np.hypot(rows - 60, cols - 60) * CELL
    far = euclid > 0.5
    # the front starts half a cell from the source centre; FMM's first-order error adds ~1 cell
    assert np.max(np.abs(T[far] - euclid[far])) < 1.5 * CELL


def test_wall_with_door_matches_hand_computed_detour():
    H, W = 100, 200
    obs = np.zeros((H, W), bool)
    obs[:, 100] = True
    obs[80:90, 100] = False  # door cells rows 80..89 -> centre row 84.5
    src = np.zeros((H, W), bool)
    src[20, 60] = True
    T = geodesic_distance(1.0, src, obs, CELL)
    door = np.array([84.5, 100.0])
    a, b = np.array([20, 60]), np.array([20, 140])
    # shortest path bends at the door edge nearest the straight line (row 80)
    edge = np.array([80.0, 100.0])
    detour = (np.linalg.norm(edge - a) + np.linalg.norm(b - edge)) * CELL
    assert np.linalg.norm(door - a) > 0  # sanity of the layout
    assert T[20, 140] == pytest.approx(detour, rel=0.03)


def test_blocked_and_unreachable_cells_are_inf_and_torch_in_torch_out():
    obs = np.zeros((50, 50), bool)
    obs[:, 25] = True
    src = np.zeros((50, 50), bool)
    src[10, 10] = True
    T = geodesic_distance(torch.ones(50, 50), torch.from_numpy(src), torch.from_numpy(obs), CELL)
    assert isinstance(T, torch.Tensor)
    assert torch.isinf(T[:, 25]).all() and torch.isinf(T[:, 30:]).all()
    assert T[10, 10] == 0 and torch.isfinite(T[:, :25]).all()


def test_no_source_gives_all_inf_never_nan():
    T = geodesic_distance(1.0, np.zeros((10, 10), bool), None, CELL)
    assert np.isinf(T).all()


def test_higher_cost_means_longer_travel_time():
    src = np.zeros((40, 40), bool)
    src[20, 5] = True
    cost = np.ones((40, 40))
    T1 = geodesic_distance(cost, src, None, CELL)
    T2 = geodesic_distance(cost * 2.0, src, None, CELL)
    np.testing.assert_allclose(T2, 2.0 * T1, rtol=1e-9)


def test_inflation_is_exact_euclidean():
    occ = np.zeros((41, 41), bool)
    occ[20, 20] = True
    inflated = inflate_obstacles(occ, 0.18, CELL)
    rows, cols = np.nonzero(inflated)
    d = np.hypot(rows - 20, cols - 20) * CELL
    assert d.max() <= 0.18 + 1e-9
    assert inflated.sum() == np.sum(np.hypot(*np.mgrid[-20:21, -20:21]) * CELL <= 0.18)
