"""Navigator (S2 behaviour) and pure-pursuit follower on synthetic depth and poses."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tests.agent.navigator.navigator_scenes import (
    LOOKAHEAD,
    ROOM,
    N,
    make_nav,
    navigator_config,
    room_depth,
    tick,
    wall_goal,
)
from vla_gr.agent.followers.pure_pursuit import (
    PurePursuit,
    PursuitConfig,
    clearance_ahead,
    pursuit_action,
)
from vla_gr.agent.navigator.navigator import Navigator, NavPlan
from vla_gr.core.gr_field.mapping import FREE_HITS, OCC_HITS
from vla_gr.geometry.pose2d import lookahead_target


def test_look_around_turns_in_place_until_a_full_turn():
    nav = make_nav()
    yaw, modes = 0.0, []
    for _ in range(80):
        plan = tick(nav, (0.0, 0.0, yaw))
        modes.append(plan.mode)
        if plan.mode != "look_around":
            break
        assert plan.command is not None and plan.command[0] == 0.0 and plan.command[1] > 0
        assert not plan.stop and len(plan.waypoints) == 0
        yaw += 0.1 * plan.command[1]  # 1 rad/s at 10 Hz
    n_look = modes.count("look_around")
    assert n_look == math.ceil(2 * math.pi / 0.1)  # the tick that sees the full turn leaves
    assert modes[-1] == "explore"


@pytest.mark.parametrize("completes", [False, True])
def test_a_goal_confirmed_during_the_look_around_ends_it_unless_it_completes(completes):
    nav = make_nav(
        look_around={"completes": completes},
        confirmation={"ticks": 2},
        approach={"stop_distance": 10.0, "stop_distance_at_end": 10.0},
    )
    yaw, modes = 0.0, []
    for _ in range(80):
        depth = room_depth((0.0, 0.0, yaw))
        plan = nav.plan({"depth": depth, "pose": np.array((0.0, 0.0, yaw), np.float32)},
                        wall_goal(depth), 1.0)  # fmt: skip
        modes.append(plan.mode)
        if plan.mode != "look_around":
            break
        yaw += 0.1 * plan.command[1]
    n_full = math.ceil(2 * math.pi / 0.1)  # ticks of a whole turn (see the test above)
    assert nav.committed  # the wall ahead became a goal on the second tick, within reach
    if completes:
        assert modes == ["look_around"] * n_full + ["stop"]  # STOP only after the whole turn
    else:
        assert modes == ["look_around", "stop"]


def test_single_tick_false_positive_does_not_commit_but_repeated_evidence_does():
    nav = make_nav(look_around={"angle": 0.0}, confirmation={"ticks": 2})
    pose = (0.0, 0.0, 0.0)
    like = wall_goal(room_depth(pose))
    plan = tick(nav, pose, like)  # one tick of goal pixels
    assert not nav.committed and plan.mode == "explore"
    assert not nav.field.maps.goal.any()  # the field plans to no goal
    for _ in range(3):
        plan = tick(nav, pose)  # the "goal" vanished
    assert not nav.committed and plan.mode == "explore"
    nav.reset()
    nav.config.look_around.angle = 0.0
    tick(nav, pose, like)
    plan = tick(nav, pose, like)  # a second tick confirms
    assert nav.committed and plan.mode == "approach"
    assert plan.goal_confidence == 1.0 and len(plan.waypoints) > 0
    assert plan.waypoints[0, 0] > 0  # heads towards the wall ahead


@pytest.mark.parametrize("threshold", [0.0, 0.5])
def test_frames_the_goal_head_calls_goal_free_cast_no_votes(threshold):
    pose = (0.0, 0.0, 0.0)
    like = wall_goal(room_depth(pose))
    nav = make_nav(look_around={"angle": 0.0}, confirmation={"visible_threshold": threshold})
    for _ in range(3):
        tick(nav, pose, like, visible=0.3)  # goal pixels, but "not in view" at p = 0.3
    assert nav.committed == (threshold == 0.0)  # gated at 0.5; pixels alone decide at 0
    assert nav.goal_votes.max() == (3 if threshold == 0.0 else 0)
    tick(nav, pose, like, visible=0.5)  # at the threshold: votes again
    tick(nav, pose, like, visible=0.9)
    assert nav.committed
    seen = nav.tick_goal_pixels
    assert seen > 0
    tick(nav, pose, like, visible=0.3)  # gated: a tick that casts no votes counts no pixels
    assert nav.tick_goal_pixels == (0 if threshold else seen)


def test_stop_only_when_the_confirmed_goal_is_within_stop_distance():
    far, near = (0.0, 0.0, 0.0), (ROOM[1] - 0.6, 0.0, 0.0)  # 3 m and 0.6 m from the wall
    nav = make_nav(look_around={"angle": 0.0}, approach={"stop_distance": 0.8})
    for _ in range(3):
        plan = tick(nav, far, wall_goal(room_depth(far)))
        assert not plan.stop
    assert plan.mode == "approach" and plan.goal_distance > 2.5
    nav = make_nav(look_around={"angle": 0.0}, approach={"stop_distance": 0.8})
    plan = tick(nav, near, wall_goal(room_depth(near)))
    assert not plan.stop  # seen once: not yet confirmed
    plan = tick(nav, near, wall_goal(room_depth(near)))
    assert plan.stop and plan.mode == "stop" and plan.goal_distance <= 0.8
    nav = make_nav(look_around={"angle": 0.0}, approach={"stop_distance": 0.8})
    for _ in range(2):
        tick(nav, near, wall_goal(room_depth(near)))
    turned = (near[0], near[1], math.pi)  # confirmed, near, but looking away: verify first
    plan = tick(nav, turned)
    assert not plan.stop and plan.mode == "verify" and plan.command[0] == 0.0


def test_stop_evidence_records_the_stop_tick_only():
    near = (ROOM[1] - 0.6, 0.0, 0.0)
    nav = make_nav(look_around={"angle": 0.0}, approach={"stop_distance": 0.8})
    like = wall_goal(room_depth(near))
    tick(nav, near, like, visible=0.7)
    assert nav.stop_evidence == {}  # no STOP yet
    plan = tick(nav, near, like, visible=0.9)
    assert plan.stop
    ev = dict(nav.stop_evidence)
    assert ev["goal_visible"] == 0.9 and ev["tick"] == 1 and ev["peak_likelihood"] == 1.0
    assert ev["goal_pixels"] >= nav.config.confirmation.min_goal_pixels
    assert ev["max_votes"] == 2 and ev["total_votes"] == 2 * ev["goal_cells"]
    assert ev["distance"] == pytest.approx(plan.goal_distance, abs=1e-3)
    tick(nav, near, like, visible=0.1)  # a later STOP tick does not overwrite it
    assert nav.stop_evidence == ev
    nav.reset()
    assert nav.stop_evidence == {}


def test_blocked_fires_after_the_window_marks_an_obstacle_and_backs_up():
    nav = make_nav(look_around={"angle": 0.0}, recovery={"blocked_steps": 10, "stuck_steps": 1000})
    pose = (0.0, 0.0, 0.0)
    like = wall_goal(room_depth(pose))  # a goal straight ahead: the plan drives forward
    modes = [tick(nav, pose, like).mode for _ in range(12)]
    assert modes[:11] == ["explore"] + ["approach"] * 10  # confirmed at tick 2, window 10
    assert modes[11] == "recover" and nav.recoveries == 1
    plan = tick(nav, pose, like)
    assert plan.mode == "recover" and plan.command[0] < 0.0  # backs up first
    r, c = nav.field.grid.world_to_cell(np.array([0.3, 0.0]))
    near = nav.field.evidence()[OCC_HITS, r - 1 : r + 2, c - 1 : c + 2]  # (3, 3) around it
    assert near.max() >= nav.config.map_edits.obstacle_hits  # a virtual obstacle in front
    nav.map_edits.clear_virtual_obstacles()
    assert nav.field.evidence()[OCC_HITS, r - 1 : r + 2, c - 1 : c + 2].max() < 10


def test_no_progress_fires_after_the_window_without_a_virtual_obstacle():
    nav = make_nav(look_around={"angle": 0.0}, recovery={"stuck_steps": 10, "blocked_steps": 1000})
    pose = (0.0, 0.0, 0.0)
    modes = [tick(nav, pose).mode for _ in range(12)]
    assert modes[:10] == ["explore"] * 10  # window not full yet
    assert modes[10] == "recover" and nav.recoveries == 1 and not nav.map_edits.virtual
    moving = make_nav(
        look_around={"angle": 0.0}, recovery={"stuck_steps": 10, "blocked_steps": 1000}
    )
    modes = [tick(moving, (0.05 * k, 0.0, 0.0)).mode for k in range(12)]
    assert "recover" not in modes  # 0.5 m in the window is progress


def test_durations_scale_with_plan_every():
    nav = Navigator(navigator_config(recovery={"stuck_steps": 40}), plan_every=3, lookahead=0.6)
    assert nav.steps_to_ticks(40) == 14 and nav.steps_to_ticks(0) == 0
    assert nav.positions.maxlen == 15  # the stuck window in ticks, plus the current one
    with pytest.raises(ValueError, match="plan_every"):
        Navigator(plan_every=0, lookahead=LOOKAHEAD)
    with pytest.raises(ValueError, match="lookahead"):
        Navigator(lookahead=0.0)
    with pytest.raises(ValueError, match=r"model\.navigator\.approach\.stop_distance=-1\.0"):
        navigator_config(approach={"stop_distance": -1.0})


def test_pursuit_turns_left_for_a_left_waypoint_and_drives_straight_ahead():
    cfg = PursuitConfig()
    v, w = pursuit_action(np.array([1.0, 0.5]), cfg)
    assert w > 0 and v > 0
    v, w = pursuit_action(np.array([1.0, -0.5]), cfg)
    assert w < 0
    v, w = pursuit_action(np.array([1.0, 0.0]), cfg)
    assert v == pytest.approx(1.0) and w == pytest.approx(0.0)
    v, w = pursuit_action(np.array([-1.0, 0.1]), cfg)  # behind: turn in place
    assert v == 0.0 and w > 0
    v, w = pursuit_action(np.array([1.0, 0.0]), cfg, clearance=cfg.stop_distance)
    assert v == 0.0  # an obstacle at the stop distance ahead: no forward motion


def test_pursuit_actions_stay_in_range():
    rng = np.random.default_rng(0)
    follower = PurePursuit()
    depth = np.full((N, N, 1), 5.0, np.float32)
    for _ in range(200):
        wps = rng.normal(scale=3.0, size=(8, 2))
        follower.set_plan(NavPlan(wps, "explore", 0.0, False), rng.normal(size=3))
        a = follower.act(depth, rng.normal(size=3))
        assert a.shape == (3,) and np.all(np.abs(a) <= 1.0) and a[2] < 0


def test_follower_carries_waypoints_by_odometry_between_ticks():
    follower = PurePursuit()
    depth = room_depth((0.0, 0.0, 0.0), room=(-30, 30, -30, 30))
    wps = np.array([[0.5 * k, 0.0] for k in range(1, 9)])  # straight ahead of the tick pose
    follower.set_plan(NavPlan(wps, "explore", 0.0, False), np.zeros(3))
    a = follower.act(depth, np.array([0.5, 0.0, 0.0]))  # moved along the path
    assert a[0] > 0.9 and abs(a[1]) < 1e-6
    a = follower.act(depth, np.array([0.5, 0.0, math.pi / 2]))  # turned left: path on the right
    assert a[0] == 0.0 and a[1] < 0
    follower.set_plan(NavPlan(np.zeros((0, 2)), "stop", 1.0, True), np.zeros(3))
    assert follower.act(depth, np.zeros(3))[2] > 0


def test_depth_clearance_sees_a_wall_ahead_and_ignores_the_floor():
    cfg = PursuitConfig()
    assert clearance_ahead(room_depth((0.0, 0.0, 0.0), room=(-9, 9, -9, 9)), cfg) > 8.0
    wall = room_depth((ROOM[1] - 0.5, 0.0, 0.0))
    assert clearance_ahead(wall, cfg) == pytest.approx(0.5, abs=1e-3)


def test_lookahead_skips_passed_waypoints():
    wps = np.array([[-1.0, 0.0], [0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    target = lookahead_target(wps, 0.6)
    assert target == pytest.approx([0.6, 0.0])


def test_noise_is_forgotten_but_real_obstacles_stay():
    nav = make_nav(look_around={"angle": 0.0}, map_edits={"noise_free_ratio": 1.0})
    tick(nav, (0.0, 0.0, 0.0))
    stray, real, unseen = torch.tensor([[5, 5]]), torch.tensor([[6, 6]]), torch.tensor([[7, 7]])
    assert nav.field.evidence()[:, 5:8, 5:8].sum() == 0  # outside the room: never seen
    nav.field.mark_unseen_free(torch.cat([stray, real]))  # one free hit each
    nav.field.add_obstacle_evidence(stray, 1.0)  # one stray point, outvoted by free space
    nav.field.add_obstacle_evidence(real, 5.0)  # a real obstacle seen repeatedly
    nav.field.add_obstacle_evidence(unseen, 1.0)  # one point, no free evidence against it
    nav.map_edits.forget_noise()
    occ = nav.field.evidence()[OCC_HITS]  # (H, W)
    assert occ[5, 5] == 0.0 and occ[6, 6] == 5.0 and occ[7, 7] == 1.0


def test_visited_cells_count_as_explored_without_hiding_obstacles():
    nav = make_nav(look_around={"angle": 0.0})
    tick(nav, (0.0, 0.0, 0.0))
    r, c = nav.field.grid.world_to_cell(np.array([-0.6, 0.0]))  # behind: never seen
    assert nav.field.evidence()[:, r, c].sum() == 0
    nav.field.add_obstacle_evidence(torch.tensor([[r + 1, c]]), 3.0)  # an obstacle beside it
    assert nav.config.map_edits.visited_clear_radius == 0.8
    nav.map_edits.mark_visited(np.array([0.0, 0.0]))
    free = nav.field.evidence()[FREE_HITS]  # (H, W)
    assert free[r, c] == 1.0 and free[r + 1, c] == 0.0


def test_pursuit_turns_in_place_instead_of_arcing_into_a_near_obstacle():
    cfg = PursuitConfig()
    target = np.array([1.0, math.tan(math.radians(30.0))])  # 30 degrees left
    v, w = pursuit_action(target, cfg, ahead=math.inf)
    assert v > 0 and w > 0  # open space: an arc
    v, w = pursuit_action(target, cfg, ahead=0.5 * (cfg.stop_distance + cfg.slow_distance))
    assert v == 0.0 and w > 0  # a jamb ahead: turn first
    wall = room_depth((ROOM[1] - 0.5, 0.0, 0.0))  # a wall 0.5 m ahead
    a, half = math.radians(35.0), cfg.robot_radius + cfg.side_margin
    expected = (0.5 - half * math.sin(a)) / math.cos(a)  # the corridor's edge meets the wall
    assert clearance_ahead(wall, cfg, bearing=a) == pytest.approx(expected, abs=0.03)


def test_tight_mode_plans_thinner_and_slower_then_restores_the_radius():
    nav = make_nav(look_around={"angle": 0.0}, tight={"steps": 3, "radius": 0.05})
    pose = (0.0, 0.0, 0.0)
    assert tick(nav, pose).max_speed == 1.0
    nav._start_tight()
    assert nav.field.planning_radius == 0.05
    assert nav.field_config.robot_radius == 0.18  # the configured radius is untouched
    speeds = [tick(nav, pose).max_speed for _ in range(4)]
    assert speeds[:2] == [nav.config.tight.speed] * 2 and speeds[-1] == 1.0
    assert nav.field.planning_radius == 0.18


def test_a_goal_that_fails_to_verify_is_rejected_and_a_verified_one_stops():
    near = (ROOM[1] - 0.6, 0.0, 0.0)  # 0.6 m from the wall the likelihood marks
    like = wall_goal(room_depth(near))
    nav = make_nav(
        look_around={"angle": 0.0},
        approach={"stop_distance": 0.8, "stop_visible_threshold": 0.6, "verify_steps": 3},
    )
    tick(nav, near, like, visible=0.2)
    plan = tick(nav, near, like, visible=0.2)  # confirmed and near, goal pixels in view
    assert nav.committed and not plan.stop and plan.mode == "verify"  # but p = 0.2 < 0.6
    for _ in range(2):
        plan = tick(nav, near, like, visible=0.2)
        assert plan.mode == "verify"
    plan = tick(nav, near, like, visible=0.2)  # verify_steps spent: rejected, explore on
    assert not plan.stop and plan.mode == "explore" and nav.rejections == 1
    assert nav.goal_votes.max() == 0 and nav.rejected.any()
    assert [r["reason"] for r in nav.rejection_log] == ["verify"]
    for _ in range(3):  # the rejected cells collect no votes again, even at p = 1
        plan = tick(nav, near, like, visible=1.0)
    assert not nav.committed and not plan.stop and nav.goal_votes.max() == 0
    # the same goal with a verifying head stops on the tick it is confirmed
    nav = make_nav(
        look_around={"angle": 0.0}, approach={"stop_distance": 0.8, "stop_visible_threshold": 0.6}
    )
    tick(nav, near, like, visible=0.2)
    plan = tick(nav, near, like, visible=0.6)
    assert plan.stop and nav.rejections == 0
    # off (0): after verify_steps without goal pixels the robot stops anyway, as before
    nav = make_nav(look_around={"angle": 0.0}, approach={"stop_distance": 0.8, "verify_steps": 1})
    for _ in range(2):
        tick(nav, near, like, visible=0.0)
    turned = (near[0], near[1], math.pi)
    assert tick(nav, turned).mode == "verify"
    assert tick(nav, turned).stop and nav.rejections == 0


def _dead_end_setup(**sections):
    """A navigator committed to a goal cluster it cannot see, and a field output whose path
    ends at the robot (the last waypoint 0.1 m ahead)."""
    nav = make_nav(look_around={"angle": 0.0}, **sections)
    pose = np.array([0.0, 0.0, 0.0])
    tick(nav, pose)  # the field has maps
    nav.goal_votes[40:42, 36:38] = 5  # a confirmed goal ~0.7 m to the robot's left
    nav.committed, nav.mode = True, "approach"
    h = nav.field.cell_size
    nearest = np.array([(36 + 0.5) * h, (40 + 0.5) * h])  # (x, y) from the grid corner
    robot_xy = nav.field.maps.robot_xy[0].numpy()

    def decide(last_waypoint, reachable=True):
        waypoints = torch.tensor([[[0.05, 0.0]] * 7 + [[last_waypoint, 0.0]]])  # (1, 8, 2)
        out = SimpleNamespace(
            has_path=torch.tensor([True]),
            goal_seen=torch.tensor([reachable]),  # False: the path leads to the frontier
            waypoints=waypoints,
        )
        # not within stop distance in line of sight: distance inf
        return nav._decide(out, pose, robot_xy, True, 1.0, math.inf, nearest)

    return nav, decide


def test_a_goal_the_robot_stands_at_the_dead_end_of_is_rejected():
    nav, decide = _dead_end_setup(approach={"dead_end_steps": 3})
    for _ in range(2):
        plan = decide(last_waypoint=0.1)
        assert plan.mode == "approach" and nav.rejections == 0
    plan = decide(last_waypoint=0.1)  # the third tick at the dead end
    assert plan.mode == "explore" and plan.command == (0.0, nav.config.turn_rate)
    assert nav.rejections == 1 and nav.goal_votes.max() == 0
    assert nav.rejected[40:42, 36:38].all() and nav.rejected[38, 36]  # with its rim
    # the log holds the reason and the goal cell's centre in the episode-start frame
    (entry,) = nav.rejection_log
    h, origin = nav.field.cell_size, nav.field.grid.origin_x
    assert entry["reason"] == "dead_end"
    assert entry["xy"] == pytest.approx([origin + 36.5 * h, origin + 40.5 * h], abs=1e-3)
    assert not nav.rejected[20, 20]  # elsewhere the map still takes votes
    # a path that still leads somewhere, or the rule off: never rejected
    for steps, last in ((3, 1.5), (0, 0.1)):
        nav, decide = _dead_end_setup(approach={"dead_end_steps": steps})
        for _ in range(10):
            assert decide(last_waypoint=last).mode == "approach"
        assert nav.rejections == 0


def test_a_goal_the_field_finds_no_way_to_for_unreachable_steps_is_rejected():
    # tight planning starts after 2 ticks without a way; it does not restart the count
    nav, decide = _dead_end_setup(approach={"unreachable_steps": 5}, recovery={"no_path_steps": 2})
    for k in range(4):
        assert decide(last_waypoint=1.5, reachable=False).mode == "approach"
        assert nav.rejections == 0
        assert nav.tight_left > 0 or k < 1  # planning thinner from the second tick on
    plan = decide(last_waypoint=1.5, reachable=False)  # the fifth tick on end
    assert plan.mode == "explore" and plan.command == (0.0, nav.config.turn_rate)
    assert nav.rejections == 1 and nav.goal_votes.max() == 0
    assert nav.rejected[40:42, 36:38].all()
    assert nav.rejection_log[0]["reason"] == "unreachable"
    # a tick with a way to the goal starts the count again; the rule off never rejects
    nav, decide = _dead_end_setup(approach={"unreachable_steps": 5})
    for k in range(12):
        assert decide(last_waypoint=1.5, reachable=k % 4 == 3).mode == "approach"
    assert nav.rejections == 0
    nav, decide = _dead_end_setup(approach={"unreachable_steps": 0})
    for _ in range(12):  # (more ticks without moving would start a recovery)
        assert decide(last_waypoint=1.5, reachable=False).mode == "approach"
    assert nav.rejections == 0


def test_a_robot_trapped_in_one_spot_closes_the_way_ahead_or_rejects_its_goal():
    nav = make_nav(look_around={"angle": 0.0}, traps={"recoveries": 3, "radius": 0.5})
    pose = np.array([0.0, 0.0, 0.0])
    tick(nav, pose)
    ahead = tuple(nav.map_edits.disk_cells(np.array([0.55, 0.0]), 0.01)[0].tolist())  # (row, col)

    def occ_ahead() -> float:
        return float(nav.field.evidence()[OCC_HITS][ahead])

    nav._start_recovery(np.array([1.5, 0.0, 0.0]), mark=False)  # elsewhere: not this spot
    for k in range(2):
        nav._start_recovery(pose + [0.1 * k, 0.0, 0.0], mark=True)
    assert nav.traps == 0 and occ_ahead() == 0
    nav._start_recovery(pose, mark=True)  # the third within 0.5 m
    assert nav.traps == 1 and occ_ahead() >= nav.config.map_edits.obstacle_hits
    nav.map_edits.clear_virtual_obstacles()  # no path: virtual obstacles go, the lasting one stays
    assert occ_ahead() >= nav.config.map_edits.obstacle_hits
    # committed to a goal: the goal is rejected instead
    nav, decide = _dead_end_setup(traps={"recoveries": 2})
    h = nav.field.cell_size
    nearest = np.array([(36 + 0.5) * h, (40 + 0.5) * h])
    for _ in range(2):
        nav._start_recovery(np.zeros(3), mark=False, nearest=nearest)
    assert nav.traps == 1 and nav.rejections == 1 and nav.goal_votes.max() == 0
    assert nav.rejection_log[0]["reason"] == "trap"
    # without traps.rejects_goal the goal keeps its votes and the way ahead is closed instead
    nav, _ = _dead_end_setup(traps={"recoveries": 2, "rejects_goal": False})
    ahead = tuple(nav.map_edits.disk_cells(np.array([0.55, 0.0]), 0.01)[0].tolist())
    for _ in range(2):
        nav._start_recovery(np.zeros(3), mark=False, nearest=nearest)
    assert nav.traps == 1 and nav.rejections == 0 and nav.goal_votes[40:42, 36:38].min() == 5
    occ = nav.field.evidence()[OCC_HITS]  # (H, W)
    assert occ[ahead] >= nav.config.map_edits.obstacle_hits and not nav.map_edits.virtual


def test_rejecting_at_a_cell_outside_any_confirmed_goal_rejects_only_its_neighbourhood():
    nav, _ = _dead_end_setup()
    h = nav.field.cell_size
    nav.goal_votes[10, 10] = 1  # a vote elsewhere, below confirmation.ticks
    nav._reject_goal(np.array([(20 + 0.5) * h, (20 + 0.5) * h]), "trap")  # (20, 20): no goal
    assert nav.rejected.sum() == 25 and nav.rejected[18:23, 18:23].all()
    assert nav.goal_votes[40:42, 36:38].min() == 5 and nav.goal_votes[10, 10] == 1
