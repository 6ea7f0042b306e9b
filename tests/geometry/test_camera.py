"""Camera maths: intrinsics, back-projection against analytic geometry, pose transforms."""

import math

import numpy as np
import pytest
import torch

from vla_gr.geometry.camera import (
    column_bearings,
    depth_to_camera_points,
    ego_to_world,
    intrinsics_from_hfov,
    project_depth,
    world_to_ego,
)


def wall_depth(n: int, distance: float, hfov: float = 79.0, camera_height: float = 0.88):
    """(n, n) z-depth of a wall facing the camera at ``distance`` over a floor (analytic)."""
    K = intrinsics_from_hfov(n, n, hfov)
    down = (np.arange(n) + 0.5 - K.cy) / K.fy  # (n,) slope of each row's ray
    floor = np.where(down > 0, camera_height / np.maximum(down, 1e-12), np.inf)
    return np.repeat(np.minimum(distance, floor)[:, None], n, axis=1).astype(np.float32)


def test_intrinsics_from_hfov():
    K = intrinsics_from_hfov(64, 64, 90.0)
    assert K.fx == pytest.approx(32.0) and K.fy == K.fx and (K.cx, K.cy) == (32.0, 32.0)
    K = intrinsics_from_hfov(128, 96, 79.0)
    assert math.degrees(2 * math.atan(64 / K.fx)) == pytest.approx(79.0)
    with pytest.raises(ValueError, match="hfov"):
        intrinsics_from_hfov(64, 64, 180.0)
    with pytest.raises(ValueError, match="width"):
        intrinsics_from_hfov(0, 64, 90.0)


def test_back_projection_of_a_fronto_parallel_wall():
    n, D, hfov = 64, 2.5, 90.0
    depth = torch.full((1, n, n), D)
    pts = depth_to_camera_points(depth, hfov)[0]  # (n, n, 3) forward, left, up
    assert torch.allclose(pts[..., 0], torch.tensor(D))
    # outermost pixel centres sit (n/2 - 0.5) / fx * D to the side, fx = n/2 for 90 deg
    assert float(pts[0, 0, 1]) == pytest.approx(D * (n / 2 - 0.5) / (n / 2))  # left edge
    assert float(pts[0, -1, 1]) == pytest.approx(-D * (n / 2 - 0.5) / (n / 2))
    assert float(pts[0, 0, 2]) > 0 > float(pts[-1, 0, 2])  # row 0 is the top
    bearings = column_bearings(n, hfov)
    assert torch.allclose(torch.atan2(pts[0, :, 1], pts[0, :, 0]).double(), bearings, atol=1e-6)


def test_project_depth_lands_wall_and_floor_at_analytic_positions():
    n, D = 64, 3.0
    depth = torch.from_numpy(wall_depth(n, D))[None, ..., None]  # (1, n, n, 1)
    pose = torch.tensor([[1.0, -2.0, math.pi / 2]])  # facing +y
    pts, valid = project_depth(depth, 79.0, pose)  # (1, N, 3), (1, N)
    assert valid.all()
    pts = pts[0].reshape(n, n, 3)
    on_wall = torch.from_numpy(wall_depth(n, D) == D)  # (n, n)
    # facing +y from (1, -2): the wall plane is y = -2 + D, floor points have height 0
    assert torch.allclose(pts[on_wall][:, 1], torch.tensor(-2.0 + D), atol=1e-5)
    assert torch.allclose(pts[~on_wall][:, 2], torch.tensor(0.0), atol=1e-5)
    assert float(pts[on_wall][:, 2].max()) == pytest.approx(0.88 + D * (n / 2 - 0.5) / 39.06, 0.02)
    # the image's left edge is at larger -x when facing +y
    assert float(pts[0, 0, 0]) < 1.0 < float(pts[0, -1, 0])


def test_invalid_depth_is_masked_never_propagated():
    depth = torch.full((2, 8, 8), 2.0)
    depth[0, 1, 1] = float("nan")
    depth[0, 2, 2] = float("inf")
    depth[1, 3, 3] = -1.0
    depth[1, 4, 4] = 0.0
    depth[1, 5, 5] = 50.0  # beyond max_depth
    pts, valid = project_depth(depth, 79.0, torch.zeros(2, 3), max_depth=10.0)
    assert torch.isfinite(pts).all()
    assert (~valid).sum() == 5
    assert not valid[0, 1 * 8 + 1] and not valid[1, 5 * 8 + 5] and valid[1, 6 * 8 + 6]
    assert torch.all(pts[~valid] == 0)


def test_ego_world_round_trip_and_known_rotation():
    gen = torch.Generator().manual_seed(0)
    pose = torch.randn(3, 3, generator=gen, dtype=torch.float64)
    pts = torch.randn(3, 10, 3, generator=gen, dtype=torch.float64)
    back = world_to_ego(ego_to_world(pts, pose), pose)
    torch.testing.assert_close(back, pts)
    one = ego_to_world(torch.tensor([[[1.0, 0.0]]]), torch.tensor([[2.0, 3.0, math.pi / 2]]))
    torch.testing.assert_close(one, torch.tensor([[[2.0, 4.0]]]))
    with pytest.raises(ValueError, match="pose"):
        ego_to_world(pts, torch.zeros(3, 2))


def test_box_room_depth_is_analytic():
    from vla_gr.geometry.camera import box_room_depth

    n, h = 32, 0.88
    depth = box_room_depth((0.0, 0.0, 0.0), (-4.0, 3.0, -10.0, 10.0), n, 79.0, h)  # (n, n)
    K = intrinsics_from_hfov(n, n, 79.0)
    up = -((np.arange(n) + 0.5) - K.cy) / K.fy  # (n,) per unit depth, rows
    above = up > 0
    # a wall facing the camera has constant planar depth: its distance
    np.testing.assert_allclose(depth[above][:, n // 2 - 4 : n // 2 + 4], 3.0, rtol=1e-6)
    # the floor below the horizon: camera height over the ray's drop per unit depth
    floor = np.minimum(h / -up[~above], 3.0)  # rows below; the wall still bounds them
    np.testing.assert_allclose(depth[~above][:, n // 2], floor, rtol=1e-5)
