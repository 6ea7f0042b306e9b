"""The fine local planner (gaps judged at the real radius on fine cells, its follower mode) and
when the navigator plans thin, which is when it runs."""

import math

import numpy as np
import pytest
import torch

from tests.agent.navigator.navigator_scenes import LOOKAHEAD, navigator_config
from vla_gr.agent.followers.pure_pursuit import PurePursuit, PursuitConfig
from vla_gr.agent.navigator.config import LocalPlannerConfig
from vla_gr.agent.navigator.local_planner import LocalPlanner
from vla_gr.agent.navigator.navigator import Navigator, NavPlan
from vla_gr.core.gr_field import GRFieldConfig
from vla_gr.core.gr_field.mapping import centred_grid
from vla_gr.geometry.camera import box_room_depth

CELL, SIZE = 0.15, 48  # coarse map: 7.2 m side
WALL_Y = 3.6  # m from the grid corner: a wall across the map with one gap


def wall_planner(gap: float, **settings) -> tuple[LocalPlanner, np.ndarray]:
    """A planner (its section only: ``LocalPlannerConfig(enabled=True, **settings)``) whose
    fine cells hold a wall of points at WALL_Y with a ``gap`` (m) centred at x = 3.6, and the
    wall points' positions (P, 2) from the grid corner."""
    cfg = LocalPlannerConfig(enabled=True, **settings)
    planner = LocalPlanner(centred_grid(SIZE, CELL), 0.18, cfg, 0.1, 1.2)
    f = planner.cell
    cols = np.arange(planner.hits.shape[-1])
    centres = (cols + 0.5) * f  # (W,) fine cell centres, metres
    wall = cols[np.abs(centres - 3.6) > gap / 2 + 0.5 * f]  # the gap is at least `gap` wide
    row = int(WALL_Y / f)
    planner.hits[0, 0, row, wall] = 1.0
    points = np.stack([(wall + 0.5) * f, np.full(len(wall), (row + 0.5) * f)], axis=-1)
    return planner, points


def room_obs() -> dict:
    """The observation at the centre of an empty 6 x 4 m box room (32 px depth, pose 0)."""
    pose = np.zeros(3, np.float32)
    depth = box_room_depth(pose, (-3.0, 3.0, -2.0, 2.0), 32, 79.0, 0.88)[..., None]
    return {"depth": depth, "pose": pose}


def thin_navigator(**sections) -> Navigator:
    fcfg = GRFieldConfig(map_size=64, cell_size=0.15, ego_size=16)
    config = navigator_config(look_around={"angle": 0.0}, **sections)
    return Navigator(config, fcfg, lookahead=LOOKAHEAD)


def travel_upwards() -> np.ndarray:
    """Coarse travel time (H, W) to the top edge, through the gap for cells below the wall
    (a thin robot's field: it knows the gap, not whether the real robot fits)."""
    centres = (np.arange(SIZE) + 0.5) * CELL
    x, y = np.meshgrid(centres, centres)  # (H, W) each
    above = SIZE * CELL - y
    below = SIZE * CELL - WALL_Y + np.hypot(x - 3.6, y - WALL_Y)
    return np.where(y > WALL_Y, above, below)


def test_a_gap_wider_than_the_robot_plus_margin_is_passed_with_that_clearance():
    planner, wall = wall_planner(gap=0.50)
    robot = np.array([3.0, WALL_Y - 1.0])  # below the wall, off the gap's axis
    path = planner.plan(robot, travel_upwards(), np.zeros((SIZE, SIZE), bool))
    assert path is not None
    assert np.linalg.norm(path[0] - robot) < 2 * planner.cell  # starts at the robot
    assert path[-1, 1] > WALL_Y + 0.3  # through the gap
    gaps = np.linalg.norm(path[:, None] - wall[None], axis=-1).min(axis=1)  # (N,)
    assert gaps.min() >= planner.radius - planner.cell  # never nearer than radius + margin


def test_a_gap_narrower_than_the_robot_plus_margin_is_not_passed():
    planner, _ = wall_planner(gap=0.36)  # exactly the robot's width: no margin left
    robot = np.array([3.0, WALL_Y - 1.0])
    path = planner.plan(robot, travel_upwards(), np.zeros((SIZE, SIZE), bool))
    assert path is None or path[:, 1].max() < WALL_Y - planner.radius + planner.cell


def test_a_marked_obstacle_without_points_closes_the_gap():
    planner, _ = wall_planner(gap=0.50)
    occupied = np.zeros((SIZE, SIZE), bool)
    occupied[int(WALL_Y / CELL), int(3.6 / CELL)] = True  # a coarse cell in the gap, no points
    robot = np.array([3.0, WALL_Y - 1.0])
    path = planner.plan(robot, travel_upwards(), occupied)
    assert path is None or path[:, 1].max() < WALL_Y


def test_a_lone_point_narrows_no_gap_with_min_hits():
    robot = np.array([3.0, WALL_Y - 1.0])
    paths = {}
    for min_hits in (1, 2):
        planner, _ = wall_planner(gap=0.50, min_hits=min_hits)
        planner.hits *= 3.0  # the wall seen on three frames
        f = planner.cell
        planner.hits[0, 0, int(WALL_Y / f), int(3.6 / f)] = 1.0  # one stray point in the gap
        paths[min_hits] = planner.plan(robot, travel_upwards(), np.zeros((SIZE, SIZE), bool))
    assert paths[1] is None or paths[1][:, 1].max() < WALL_Y  # the point closes the gap
    assert paths[2] is not None and paths[2][-1, 1] > WALL_Y + 0.3  # seen once: noise


def test_no_local_plan_without_progress_in_the_travel_time():
    planner, _ = wall_planner(gap=0.50, min_progress=0.3)
    robot = np.array([3.0, WALL_Y - 1.0])
    flat = np.full((SIZE, SIZE), 5.0)  # no cell is nearer the goal than another
    assert planner.plan(robot, flat, np.zeros((SIZE, SIZE), bool)) is None


def test_observed_depth_points_land_on_the_fine_cells_of_their_position():
    planner, _ = wall_planner(gap=0.50)
    planner.reset()
    grid = centred_grid(SIZE, CELL)
    xyz = torch.tensor([[[0.51, -0.26, 0.5], [0.2, 0.2, 0.02]]])  # an obstacle point, floor
    planner.observe(xyz, torch.ones(1, 2, dtype=torch.bool))
    hits = planner.hits[0, 0]
    assert hits.sum() == 1.0  # the floor point is not an obstacle
    r = int((-0.26 - grid.origin_y) / planner.cell)
    c = int((0.51 - grid.origin_x) / planner.cell)
    assert hits[r, c] == 1.0


def test_the_navigator_follows_a_precise_local_path_only_while_planning_thin():
    for enabled in (False, True):
        nav = thin_navigator(local_planner={"enabled": enabled})
        obs = room_obs()
        blank = np.zeros((32, 32), np.float32)
        assert not nav.plan(obs, blank).precise
        nav._start_tight()
        plan = nav.plan(obs, blank)
        assert plan.precise == enabled
        if enabled:
            assert np.hypot(*plan.waypoints[0]) < 0.1  # robot frame, from the robot
            assert len(plan.waypoints) > 2


def test_the_follower_lets_the_robot_width_through_on_a_precise_plan_only():
    cfg = PursuitConfig()
    follower = PurePursuit(cfg)
    # a box room whose side walls are 0.20 m from the centre: inside the 0.23 m half corridor
    # of the normal check, outside the robot's 0.18 m of the precise one
    depth = box_room_depth(np.zeros(3), (-3.0, 3.0, -0.20, 0.20), 32, 79.0, 0.88)[..., None]
    straight = np.array([[0.5, 0.0], [1.0, 0.0], [1.5, 0.0]])  # (K, 2) straight ahead
    speeds = {}
    for precise in (False, True):
        follower.set_plan(NavPlan(straight, "explore", 1.0, False, precise=precise), np.zeros(3))
        speeds[precise] = float(follower.act(depth, np.zeros(3))[0])
    assert speeds[False] == 0.0 and speeds[True] > 0.5


@pytest.mark.parametrize(
    "key, value", [("cell", 0.0), ("window", -1.0), ("margin", -0.1), ("min_hits", 0)]
)
def test_local_settings_out_of_range_name_the_key(key, value):
    with pytest.raises(ValueError, match=rf"model\.navigator\.local_planner\.{key}="):
        LocalPlannerConfig(**{key: value})


def test_a_negative_precise_side_margin_is_refused():
    with pytest.raises(ValueError, match="precise_side_margin"):
        PursuitConfig(precise_side_margin=-0.01)
    assert math.isclose(PursuitConfig().precise_lookahead, 0.3)


def test_a_local_path_is_followed_until_it_is_stale_or_the_robot_leaves_it(monkeypatch):
    planner, _ = wall_planner(gap=0.50, replan_ticks=3, off_path=0.15)
    robot = np.array([3.0, WALL_Y - 1.0])
    T, occupied = travel_upwards(), np.zeros((SIZE, SIZE), bool)
    first = planner.follow(robot, T, occupied)
    calls = []
    real_plan = planner.plan
    monkeypatch.setattr(planner, "plan", lambda *a: calls.append(1) or real_plan(*a))
    moved = first[4]  # the robot drove a few steps along it
    again = planner.follow(moved, T, occupied)
    assert not calls and np.allclose(again, first[4:])  # the rest of the same path
    planner.follow(moved, T, occupied)
    assert not calls  # third tick of the plan
    planner.follow(moved, T, occupied)
    assert len(calls) == 1  # stale after replan_ticks: planned anew
    planner.follow(moved + np.array([0.3, 0.0]), T, occupied)
    assert len(calls) == 2  # off the path: planned anew at once
    planner.forget()
    planner.follow(moved + np.array([0.3, 0.0]), T, occupied)
    assert len(calls) == 3


@pytest.mark.parametrize("hold, thin", [(1, False), (9, True)])
def test_a_path_that_comes_and_goes_resets_the_no_path_count_only_when_held(
    hold, thin, monkeypatch
):
    nav = thin_navigator(recovery={"no_path_steps": 3, "path_hold_steps": hold})
    real_update = nav.field.update
    flicker = iter([False, True] * 10)  # the path is lost and found tick by tick

    def update(*args, **kwargs):
        out = real_update(*args, **kwargs)
        out.has_path = torch.tensor([next(flicker)])
        return out

    monkeypatch.setattr(nav.field, "update", update)
    obs = room_obs()
    for _ in range(6):
        nav.plan(obs, np.zeros((32, 32), np.float32))
    assert (nav.tight_left > 0) == thin  # three ticks without a path, never three in a row
