"""GRField: mapping against analytic depth, view accumulation, outputs, no-path, the real world."""

import math

import numpy as np
import pytest
import torch

from vla_gr.core.gr_field import FEATURE_NAMES, GRField, GRFieldConfig, snap_start
from vla_gr.core.gr_field.mapping import FREE_HITS, GOAL_SUM, OCC_HITS, POINT_HITS
from vla_gr.geometry import camera
from vla_gr.geometry.camera import ego_to_world, intrinsics_from_hfov

HFOV, CAM_H, N = 79.0, 0.88, 64
ROOM = (-2.0, 3.0, -1.7, 2.3)  # x0, x1, y0, y1 of a box room around the start (m)


def box_room_depth(pose, room=ROOM, n=N, hfov=HFOV):
    """Analytic z-depth (n, n) of an axis-aligned box room with a floor, seen from ``pose``."""
    return camera.box_room_depth(pose, room, n, hfov, CAM_H)


def obs_of(*poses, room=ROOM):
    depth = np.stack([box_room_depth(p, room) for p in poses])[..., None]  # (B, n, n, 1)
    return {"depth": torch.from_numpy(depth), "pose": torch.tensor(poses, dtype=torch.float32)}


def cell_xy(field: GRField, rows, cols):
    return field.grid.cell_to_world(np.stack([rows, cols], -1))  # (M, 2)


def test_wall_at_known_distance_lands_in_the_analytic_cells():
    D = 2.0  # a fronto-parallel wall ahead; the room is wide enough that only it is seen
    field = GRField(map_size=128, cell_size=0.15)
    out = field.update(obs_of((0.0, 0.0, 0.0), room=(-5.0, D, -20.0, 20.0)))
    occ = field.maps.occupied[0].numpy()
    K = intrinsics_from_hfov(N, N, HFOV)
    lateral = D * (K.cx - (np.arange(N) + 0.5)) / K.fx  # (N,) y of each column's wall point
    g = field.grid
    col = int(np.floor((D - g.origin_x) / g.cell_size))
    rows = np.unique(np.floor((lateral - g.origin_y) / g.cell_size).astype(int))
    expected = np.zeros_like(occ)
    expected[rows, col] = True
    assert np.array_equal(occ, expected)
    explored = field.maps.explored[0].numpy()
    r0 = int(np.floor(-g.origin_y / g.cell_size))
    assert explored[r0, int(np.floor(-g.origin_x / g.cell_size)) : col].all()  # ray to the wall
    assert not explored[r0, col + 1 :].any()  # nothing seen behind it
    # egocentric features: the wall is a column of 'occupied' at forward = D
    ego = out.features[0, FEATURE_NAMES.index("occupied")]  # (h, w)
    fwd = (torch.arange(ego.shape[1]) + 0.5 - ego.shape[1] / 2) * 0.15  # (w,)
    assert abs(float(fwd[ego.sum(0).argmax()]) - D) <= 0.15


def test_two_views_accumulate_additively_and_agree_on_their_overlap():
    pa, pb = (0.0, 0.0, 0.0), (0.6, 0.4, 0.7)
    fa, fb, fab = GRField(), GRField(), GRField()
    fa.update(obs_of(pa))
    fb.update(obs_of(pb))
    fab.update(obs_of(pa))
    fab.update(obs_of(pb))
    for ch in (OCC_HITS, FREE_HITS, POINT_HITS):
        torch.testing.assert_close(fab.evidence()[ch], fa.evidence()[ch] + fb.evidence()[ch])
    occ_a, occ_b = fa.maps.occupied[0].numpy(), fb.maps.occupied[0].numpy()
    exp_a, exp_b = fa.maps.explored[0].numpy(), fb.maps.explored[0].numpy()
    both = exp_a & exp_b
    agree = (occ_a == occ_b)[both].mean()
    assert both.sum() > 100 and agree > 0.97
    # every occupied cell lies on a wall of the room (within one cell)
    rows, cols = np.nonzero(fab.maps.occupied[0].numpy())
    x, y = cell_xy(fab, rows, cols).T
    to_wall = np.minimum.reduce(
        [abs(x - ROOM[0]), abs(x - ROOM[1]), abs(y - ROOM[2]), abs(y - ROOM[3])]
    )
    assert to_wall.max() <= 0.15


def test_an_update_with_the_callers_projection_equals_one_that_projects_itself():
    poses = [(0.0, 0.0, 0.0), (0.6, 0.4, 0.7)]
    own, given = GRField(), GRField()
    for pose in poses:
        obs = obs_of(pose)
        a = own.update(obs)
        depth = obs["depth"][..., 0].float()  # (1, n, n)
        b = given.update(obs, projection=given.project(depth, obs["pose"]))
        assert torch.equal(a.waypoints, b.waypoints)
    assert torch.equal(own.map_state, given.map_state)
    points, valid = given.project(depth, obs["pose"])
    with pytest.raises(ValueError, match="projection must be"):
        given.update(obs, projection=(points[:, :-1], valid[:, :-1]))  # another frame's


def test_bad_depth_is_masked_and_never_propagated():
    obs = obs_of((0.0, 0.0, 0.3))
    clean = GRField()
    ref = clean.update({"depth": obs["depth"].clone(), "pose": obs["pose"]})
    bad = obs["depth"].clone()
    gen = torch.Generator().manual_seed(0)
    pick = torch.rand(bad.shape, generator=gen) < 0.2
    values = torch.tensor([float("nan"), float("inf"), -1.0, -float("inf")])
    bad[pick] = values[torch.randint(0, 4, (int(pick.sum()),), generator=gen)]
    masked = obs["depth"].clone()
    masked[pick] = 10.0  # a no-return at max_depth is masked as well
    f1, f2 = GRField(), GRField()
    out1 = f1.update({"depth": bad, "pose": obs["pose"]})
    f2.update({"depth": masked, "pose": obs["pose"]})
    assert torch.equal(f1.evidence(), f2.evidence())
    for t in (out1.features, out1.waypoints, f1.maps.phi_hat, f1.maps.psi):
        assert not torch.isnan(t).any()
    assert out1.has_path.all() and ref.has_path.all()


def test_all_obstacle_map_and_unreachable_sources_give_explicit_no_path():
    field = GRField(map_size=64, cell_size=0.15)
    obs = obs_of((0.0, 0.0, 0.0))
    field.update(obs)
    nothing = {"depth": torch.full_like(obs["depth"], float("nan")), "pose": obs["pose"]}
    field.map_state[:, OCC_HITS] = 1.0  # everything is an obstacle
    out = field.update(nothing)
    assert not out.has_path.any() and torch.all(out.waypoints == 0)
    assert torch.isinf(out.distance).all() and torch.isfinite(out.features).all()
    assert field.render().shape == (128, 128, 3)

    field.reset()
    field.update(obs)
    x, y = cell_xy(field, *np.mgrid[0:64, 0:64].reshape(2, -1)).T
    r = np.hypot(x, y).reshape(64, 64)
    field.map_state[0, FREE_HITS][torch.from_numpy(r < 1.0)] = 1.0  # fully seen inside a ring
    field.map_state[0, OCC_HITS][torch.from_numpy(np.abs(r - 1.1) < 0.15)] = 1.0
    out = field.update(nothing)
    assert not out.has_path.any() and not out.goal_seen.any()
    field.map_state[0, GOAL_SUM, 10, 10] = 1.0
    field.map_state[0, POINT_HITS, 10, 10] = 1.0
    out = field.update(nothing)
    assert not out.has_path.any() and torch.all(out.waypoints == 0)


def test_seen_goal_gives_a_geodesic_towards_it_with_even_spacing():
    cfg = GRFieldConfig(num_waypoints=6, waypoint_spacing=0.4)
    field = GRField(cfg)
    pose = (0.0, 0.0, 0.0)
    goal = torch.zeros(1, N, N)
    goal[0, :30, 50:58] = 1.0  # a strip of the x = 3 wall, right of the optical axis
    out = field.update(obs_of(pose), goal)
    assert out.goal_seen.all() and out.has_path.all()
    wp = out.waypoints[0]  # (6, 2)
    steps = torch.cat([wp[:1], wp[1:] - wp[:-1]]).norm(dim=-1)
    torch.testing.assert_close(steps, torch.full((6,), 0.4), atol=0.03, rtol=0)
    assert torch.all(wp[1:, 0] > wp[:-1, 0]) and wp[-1, 1] < -0.2  # forward and to the right
    assert out.distance[0] > 2.0 and torch.isfinite(out.distance).all()
    img = field.render(scale=2)
    assert img.dtype == np.uint8 and img.shape == (2 * cfg.map_size, 2 * cfg.map_size, 3)
    assert (img == 255).all(-1).sum() > 20  # the white path is drawn


def test_outputs_are_equivariant_to_a_quarter_turn_of_the_world():
    x0, x1, y0, y1 = ROOM
    turned = (-y1, -y0, x0, x1)  # the room rotated by +90 deg about the start
    goal = torch.zeros(2, N, N)
    goal[:, :30, 50:58] = 1.0
    field = GRField()
    depth = np.stack(
        [box_room_depth((0.0, 0.0, 0.0), ROOM), box_room_depth((0.0, 0.0, math.pi / 2), turned)]
    )
    np.testing.assert_allclose(depth[0], depth[1], rtol=1e-5)
    pose = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, math.pi / 2]])
    out = field.update({"depth": torch.from_numpy(depth), "pose": pose}, goal)
    assert out.has_path.all()
    torch.testing.assert_close(out.waypoints[0], out.waypoints[1], atol=0.05, rtol=0)
    same = torch.isclose(out.features[0], out.features[1], atol=1e-3).float().mean()
    assert same > 0.99


def test_batch_elements_are_independent_and_reset_clears_only_the_chosen_ones():
    pa, pb = (0.0, 0.0, 0.2), (0.5, -0.3, -0.4)
    both = GRField()
    out = both.update(obs_of(pa, pb))
    single = GRField()
    ref = single.update(obs_of(pb))
    torch.testing.assert_close(out.features[1], ref.features[0])
    torch.testing.assert_close(out.waypoints[1], ref.waypoints[0])
    both.reset([0])
    assert both.evidence(0).sum() == 0 and torch.equal(both.evidence(1), single.evidence(0))
    with pytest.raises(ValueError, match="batch size"):
        both.update(obs_of(pa))
    with pytest.raises(ValueError, match="batch_indices"):
        both.reset([5])
    gamma = both.christoffel()
    assert gamma.shape == (2, 2, 2, 2, 192, 192) and torch.isfinite(gamma).all()


def test_config_and_input_validation():
    with pytest.raises(ValueError, match="cell_size"):
        GRFieldConfig(cell_size=0.0)
    with pytest.raises(ValueError, match="goal_threshold"):
        GRFieldConfig(goal_threshold=1.5)
    field = GRField(map_size=32)
    with pytest.raises(ValueError, match="pose"):
        field.update({"depth": torch.ones(1, 8, 8), "pose": torch.zeros(2, 3)})
    with pytest.raises(ValueError, match="depth"):
        field.update({"pose": torch.zeros(1, 3)})
    with pytest.raises(ValueError, match="goal_likelihood"):
        field.update({"depth": torch.ones(1, 8, 8), "pose": torch.zeros(1, 3)}, torch.ones(1, 4, 4))
    with pytest.raises(RuntimeError):
        GRField().render()


# --------------------------------------------------------------------------- the real world


def _to_world(field: GRField, rows, cols, start):
    xy = cell_xy(field, rows, cols)  # (M, 2) map frame (episode start)
    c, s = math.cos(start[2]), math.sin(start[2])
    return np.stack(
        [start[0] + c * xy[:, 0] - s * xy[:, 1], start[1] + s * xy[:, 0] + c * xy[:, 1]], -1
    )


def test_rendered_walls_land_on_the_true_occupancy():
    gym = pytest.importorskip("gymnasium")
    from scipy import ndimage

    import vla_gr.envs  # noqa: F401  (registers the env)

    env = gym.make("VLAGR/ObjectNav-v0", image_size=64)
    try:
        obs, _ = env.reset(options={"episode": 0})
        world = env.unwrapped
        house, start = world.house, np.asarray(world.start_pose_world, float)
        field = GRField()
        field.update({"depth": obs["depth"][None], "pose": obs["pose"][None]})

        # the wall straight ahead, at a distance measured on the true occupancy grid
        hg = house.grid
        t = np.arange(0.0, 10.0, hg.cell_size / 4)
        ray = start[:2] + t[:, None] * [math.cos(start[2]), math.sin(start[2])]
        rc = hg.world_to_cell(ray)
        inside = hg.in_bounds(rc)
        hit = house.occupancy[rc[inside, 0], rc[inside, 1]]
        assert hit.any()
        true_d = float(t[inside][np.argmax(hit)])
        assert float(obs["depth"][32, 31:33].mean()) == pytest.approx(true_d, abs=0.1)
        occ = field.maps.occupied[0].numpy()
        g = field.grid
        row = int(np.floor(-g.origin_y / g.cell_size))  # the map's x axis is the start heading
        first = np.argmax(occ[row, int(np.floor(-g.origin_x / g.cell_size)) :])
        map_d = (first + 0.5) * g.cell_size
        assert map_d == pytest.approx(true_d, abs=g.cell_size + hg.cell_size)

        # turn in place and drive a little: every mapped obstacle stays on a true one
        for _ in range(8):
            obs, *_ = env.step(np.array([0.3, 1.0, -1.0], np.float32))
            field.update({"depth": obs["depth"][None], "pose": obs["pose"][None]})
        pose_err = np.asarray(world.robot_pose_world()) - start
        assert np.hypot(*pose_err[:2]) > 0.05  # it did move
        rows, cols = np.nonzero(field.maps.occupied[0].numpy())
        wrc = hg.world_to_cell(_to_world(field, rows, cols, start))
        ok = hg.in_bounds(wrc)
        near = ndimage.binary_dilation(house.occupancy, iterations=3)  # 0.15 m tolerance
        assert len(rows) > 50 and ok.all()
        assert near[wrc[:, 0], wrc[:, 1]].mean() > 0.97
    finally:
        env.close()


def test_planning_window_matches_fast_marching_on_the_whole_map():
    goal = torch.zeros(1, N, N)
    goal[0, :30, 50:58] = 1.0
    obs = obs_of((0.3, -0.2, 0.4))
    windowed, whole = GRField(), GRField(planning_margin=100.0)
    out_w, out_f = windowed.update(obs, goal), whole.update(obs, goal)
    seen = windowed.maps.explored[0] & torch.isfinite(whole.maps.travel[0])
    t_w, t_f = windowed.maps.travel[0][seen], whole.maps.travel[0][seen]
    assert seen.sum() > 200 and float(t_f.max()) > 3.0
    torch.testing.assert_close(t_w, t_f, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(out_w.waypoints, out_f.waypoints, rtol=0, atol=1e-4)
    assert torch.isinf(windowed.maps.travel[0][~seen]).any()


def test_unseen_goal_field_explores_towards_the_frontier():
    field = GRField()
    out = field.update(obs_of((0.0, 0.0, 0.0), room=(-5.0, 2.0, -20.0, 20.0)))
    assert out.has_path.all() and not out.goal_seen.any()
    last = field.maps
    frontier = last.frontier[0]
    assert frontier.any()
    # descending T from the robot ends on a frontier cell, with T falling all the way
    origin = torch.tensor([field.grid.origin_x, field.grid.origin_y])
    pose = torch.zeros(1, 3)
    pts = ego_to_world(out.waypoints, pose)[0] - origin  # (K, 2) from the grid corner
    cells = torch.floor(pts / field.grid.cell_size).long()  # (K, 2) as (col, row)
    t_path = last.travel[0][cells[:, 1], cells[:, 0]]
    assert torch.all(t_path[1:] <= t_path[:-1] + 1e-6)
    assert frontier[cells[-1, 1], cells[-1, 0]] or t_path[-1] == 0
    # the potential has its wells on the attracting (frontier) mass, not in the open
    phi = last.phi_hat[0]
    assert float(phi[frontier].mean()) < float(phi[last.explored[0] & ~frontier].mean())


def test_snap_start_steps_out_of_the_inflated_margin():
    T = np.full((10, 10), np.inf)
    T[:, 6:] = 1.0  # reachable cells: columns 6.. (centres x >= 0.65 at 0.1 m cells)
    here = np.array([0.68, 0.55])
    np.testing.assert_allclose(snap_start(T, here, 0.1, 0.3), here)  # already reachable
    np.testing.assert_allclose(snap_start(T, np.array([0.52, 0.55]), 0.1, 0.3), [0.65, 0.55])
    assert snap_start(T, np.array([0.12, 0.55]), 0.1, 0.3) is None  # too far from any
    assert snap_start(T, np.array([-5.0, 0.55]), 0.1, 0.3) is None  # off the grid


def test_robot_next_to_a_wall_still_plans_away_from_it():
    D = 0.25  # the base (radius 0.18) fits, but its centre is inside the inflated margin
    field = GRField()
    room = (-4.0, D, -3.0, 3.0)
    field.update(obs_of((0.0, 0.0, math.pi), room=room))  # look back into the room first
    out = field.update(obs_of((0.0, 0.0, 0.0), room=room))
    travel = field.maps.travel[0]
    g = field.grid
    assert torch.isinf(travel[int(-g.origin_y / g.cell_size), int(-g.origin_x / g.cell_size)])
    assert out.has_path.all() and torch.isfinite(out.waypoints).all()
    assert float(out.waypoints[0, :, 0].max()) <= 0.05  # never towards the wall
    assert float(out.waypoints[0, -1].norm()) > 0.3


def test_features_are_read_from_their_own_tick_and_cost_the_update_nothing():
    first, second = (0.0, 0.0, 0.0), (0.8, 0.4, 1.2)
    field = GRField(map_size=96)
    out1 = field.update(obs_of(first))
    assert list(field.last_timings) == [
        "mapping", "masses", "poisson", "metric", "fast_marching", "path"
    ]  # fmt: skip
    out2 = field.update(obs_of(second))
    maps = field.maps
    assert maps.occupied.any() and "phi_hat" not in vars(maps)  # the navigator's reads: no solve
    assert maps.phi_hat is maps.phi_hat and "phi_hat" in vars(maps)  # solved once when read
    ref = GRField(map_size=96)
    ref_out = ref.update(obs_of(first))
    # read after a later update, the first tick's features are still those of its own maps
    torch.testing.assert_close(out1.features, ref_out.features)
    assert not torch.allclose(out1.features, out2.features)
    assert out2.features is out2.features  # computed once, then kept
    phi = out2.features[0, FEATURE_NAMES.index("phi")]  # (h, w)
    assert float(phi.min()) >= 0.0 and float(phi.max()) <= 1.0


def _wall_with_gap(field: GRField, last_above: int, first_below: int) -> np.ndarray:
    """Obstacle points in sub-column 91 (cell column 30) at every sub-row but those strictly
    between ``last_above`` and ``first_below``; returns the cells' occupancy (64, 64)."""
    k = field.config.clearance_factor
    field.sub_hits.zero_()
    rows = [r for r in range(64 * k) if r <= last_above or r >= first_below]
    field.sub_hits[0, 0, rows, 91] = 1.0
    return field.sub_hits[0, 0].reshape(64, k, 64, k).sum(dim=(1, 3)).numpy() > 0


def test_sub_cells_judge_a_gap_by_where_its_edges_are():
    field = GRField(map_size=64, cell_size=0.15, clearance_factor=3)
    field.update(obs_of((0.0, 0.0, 0.0)))  # allocates the batch
    assert field.sub_hits.shape == (1, 1, 192, 192)
    whole = (slice(0, 64), slice(0, 64))
    # a 0.50 m gap (free sub-rows 61..70): the robot (0.36 m) fits with 0.07 m to each side,
    # but only cells 21 and 22 are wholly free, and each is next to an occupied one
    occ = _wall_with_gap(field, 60, 71)
    assert not occ[21:23, 30].any() and occ[20, 30] and occ[23, 30]
    by_cells = GRField(map_size=64, cell_size=0.15)._no_fit(0, occ, whole)
    assert by_cells[:, 30].all()  # the cells alone close it
    no_fit = field._no_fit(0, occ, whole)
    assert not no_fit[21, 30] and no_fit[occ].all()  # sub-cells open it; obstacles never fit
    # a 0.35 m gap (free sub-rows 61..67) is narrower than the robot: closed either way
    occ = _wall_with_gap(field, 60, 68)
    assert field._no_fit(0, occ, whole)[:, 30].all()


def test_sub_cells_count_the_same_points_and_marked_obstacles_fill_them():
    field = GRField(map_size=96, cell_size=0.15, clearance_factor=3)
    field.update(obs_of((0.3, -0.2, 0.4)))
    field.update(obs_of((0.0, 0.4, 2.0)))
    sub = field.sub_hits[0, 0].reshape(96, 3, 96, 3).sum(dim=(1, 3))  # (96, 96) per cell
    assert float(sub.sum()) > 100
    torch.testing.assert_close(sub, field.evidence()[OCC_HITS], rtol=0, atol=0)
    before = field.sub_hits.clone(), field.evidence()
    cells = torch.tensor([[40, 41], [50, 52]])
    field.add_obstacle_evidence(cells, 100.0)
    assert field.evidence()[OCC_HITS, 40, 41] >= 100.0
    assert bool((field.sub_hits[0, 0, 120:123, 123:126] >= 100.0).all())
    assert float(field.sub_hits.sum() - before[0].sum()) == 2 * 9 * 100.0
    field.add_obstacle_evidence(cells, -100.0)  # taken back: as before
    assert torch.equal(field.sub_hits, before[0]) and torch.equal(field.evidence(), before[1])
    with pytest.raises(ValueError, match="clearance_factor"):
        GRFieldConfig(clearance_factor=0)


def test_a_clearance_margin_closes_the_gap_the_sub_cells_opened():
    whole = (slice(0, 64), slice(0, 64))
    fields = [GRField(map_size=64, clearance_factor=3, clearance_margin=m) for m in (0.0, 0.05)]
    for field in fields:
        field.update(obs_of((0.0, 0.0, 0.0)))
    occ = _wall_with_gap(fields[0], 60, 71)  # the 0.50 m gap: 0.07 m to spare on each side
    _wall_with_gap(fields[1], 60, 71)
    assert not fields[0]._no_fit(0, occ, whole)[:, 30].all()
    assert fields[1]._no_fit(0, occ, whole)[:, 30].all()  # 0.05 m more than that: closed


def test_frontier_value_sends_the_robot_to_the_frontier_worth_searching():
    """A seen corridor with a frontier at each end, the robot 1 m from the west end and 3 m
    from the east end: it heads west by default and east once the west end is worth little."""
    field = GRField(map_size=96, cell_size=0.1)
    pose = torch.zeros(1, 3)
    (row, col), h = field.grid.world_to_cell(np.zeros(2)), field.grid.cell_size
    west, east = col - round(1.0 / h), col + round(3.0 / h)
    nothing = {"depth": torch.full((1, N, N, 1), float("nan")), "pose": pose}
    field.update(nothing)
    field.map_state[0, FREE_HITS, row - 4 : row + 5, west : east + 1] = 1.0  # the corridor
    field.map_state[0, OCC_HITS, row - 5, west : east + 1] = 1.0  # its walls
    field.map_state[0, OCC_HITS, row + 5, west : east + 1] = 1.0

    def heading(value=None, keep=0.5) -> float:
        out = field.update(nothing, frontier_value=value, frontier_keep=keep)
        assert out.has_path.all() and not out.goal_seen.any()
        return float(out.waypoints[0, -1, 0])  # forward (+x, east) of the last waypoint

    assert heading() < 0  # the nearer frontier
    value = torch.ones(1, *field.grid.shape)
    value[0, :, :col] = 0.2  # the west half of the map is worth a fifth of the east
    assert heading(value) > 0
    assert heading(value, keep=0.1) < 0  # 0.2 >= 0.1 x the best: both ends are kept
    assert heading(torch.ones(1, *field.grid.shape)) < 0  # alike everywhere: as without
    with pytest.raises(ValueError, match="frontier_value"):
        field.update(nothing, frontier_value=torch.ones(1, 5, 5))
