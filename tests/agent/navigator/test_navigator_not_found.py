"""Not found: the navigator says the reachable house is searched only after its own map has
had no confirmed goal and no way to a frontier for ``not_found.steps`` on end."""

import math

import numpy as np
import pytest

from tests.agent.navigator.navigator_scenes import make_nav, room_depth, tick, wall_goal

FULL_TURN = math.ceil(2 * math.pi / 0.1)  # look-around ticks at 1 rad/s and 10 Hz


def _searched_room(nav, ticks: int, like=None) -> list:
    """Tick ``nav`` in the closed box room: a full look around, then standing still."""
    yaw, plans = 0.0, []
    for _ in range(ticks):
        pose = (0.0, 0.0, yaw)
        goal = None if like is None else like(room_depth(pose))
        plan = tick(nav, pose, goal)
        plans.append(plan)
        if plan.mode == "look_around":
            yaw += 0.1 * plan.command[1]
    return plans


def test_a_searched_room_without_a_goal_is_not_found_after_the_steps_and_never_stops():
    nav = make_nav(not_found={"steps": 20}, tight={"steps": 10})
    plans = _searched_room(nav, FULL_TURN + 40)
    assert not any(p.stop for p in plans)
    assert not any(p.not_found for p in plans[:FULL_TURN])  # never while looking around
    first = next(k for k, p in enumerate(plans) if p.not_found)
    # the whole room was seen in the turn: no frontier, no path, from the first tick after it
    assert not nav.field.maps.frontier.any() and not nav.last_output.has_path[0]
    assert first == FULL_TURN + 20 - 1  # 20 ticks (plan_every 1) on end without a way
    assert all(p.not_found for p in plans[first:])


def test_no_declaration_when_off_or_with_a_confirmed_goal():
    off = make_nav(not_found={"steps": 0})
    assert not any(p.not_found for p in _searched_room(off, FULL_TURN + 40))
    committed = make_nav(not_found={"steps": 20}, tight={"steps": 10}, look_around={"angle": 0.0},
                         approach={"stop_distance": 0.0, "stop_distance_at_end": 0.0})  # fmt: skip
    plans = _searched_room(committed, 40, like=wall_goal)
    assert committed.committed and not any(p.not_found or p.stop for p in plans)


def test_a_room_half_seen_keeps_a_way_to_its_frontier_and_is_never_searched():
    nav = make_nav(not_found={"steps": 20}, tight={"steps": 10}, look_around={"angle": 0.0})
    for _ in range(60):  # facing one wall, the robot never turns: the rest is unseen
        plan = tick(nav, (0.0, 0.0, 0.0))
        assert not plan.not_found and nav.search.ticks == 0
    assert nav.field.maps.frontier.any() and nav.last_output.has_path[0]


def test_newly_seen_house_starts_the_count_again_and_off_never_declares():
    nav = make_nav(not_found={"steps": 20, "new_area": 2.0}, tight={"steps": 10})
    _searched_room(nav, FULL_TURN + 10)
    assert nav.search.ticks == 10
    pose = np.array((0.0, 0.0, 0.0), np.float32)
    depth = room_depth(pose, room=(-3.0, 6.0, -2.0, 2.0))  # seen through where a wall was
    plan = nav.plan({"depth": depth, "pose": pose}, np.zeros(depth.shape[:2], np.float32), 1.0)
    assert not nav.last_output.has_path[0]  # still no way (the old wall stays mapped) ...
    assert nav.search.ticks == 0 and not plan.not_found  # ... but more house was seen
    plan = nav.plan({"depth": depth, "pose": pose}, np.zeros(depth.shape[:2], np.float32), 1.0)
    assert nav.search.ticks == 1  # nothing new any more: counting again


def test_a_way_only_a_thinner_robot_takes_does_not_count_and_a_stint_alone_never_declares():
    nav = make_nav(not_found={"steps": 20}, tight={"steps": 10}, look_around={"angle": 0.0})
    tick(nav, (0.0, 0.0, 0.0))
    nav._start_tight()  # as after a while without a path: plan thinner for tight.steps
    counts = []
    for _ in range(12):
        plan = tick(nav, (0.0, 0.0, 0.0))
        assert nav.last_output.has_path[0] and not plan.not_found
        counts.append(nav.search.ticks)
    assert counts == [*range(1, 10), 0, 0, 0]  # thin ticks count; the own radius's way resets


def test_bad_steps_name_the_key_and_a_stint_of_thinner_planning_alone_never_declares():
    from vla_gr.agent.navigator.config import NavigatorConfig, NotFoundConfig, TightConfig

    with pytest.raises(ValueError, match=r"^model\.navigator\.not_found\.steps=-1 must be >= 0"):
        NotFoundConfig(steps=-1)
    with pytest.raises(ValueError, match=r"^model\.navigator\.not_found\.new_area=-1\.0 must"):
        NotFoundConfig(new_area=-1.0)
    with pytest.raises(ValueError, match=r"not_found\.steps=150 must be 0 or more than .*tight"):
        NavigatorConfig(not_found=NotFoundConfig(150), tight=TightConfig(steps=150))
    NavigatorConfig(not_found=NotFoundConfig(0), tight=TightConfig(steps=150))  # off: any
    assert NavigatorConfig().not_found.steps > NavigatorConfig().tight.steps


@pytest.mark.parametrize("second_look", [False, True])
def test_a_second_look_forgets_the_rejected_goals_once_before_declaring(second_look):
    nav = make_nav(not_found={"steps": 20, "second_look": second_look}, tight={"steps": 10})
    centre = np.array(nav.field.grid.shape[::-1], float) * nav.field.cell_size / 2  # metres
    nav._reject_goal(centre, "object")  # a goal given up: its cells vote no more
    assert nav.rejected.any() and nav.rejections == 1
    plans = _searched_room(nav, FULL_TURN + 60)
    first = next(k for k, p in enumerate(plans) if p.not_found)
    if second_look:  # searched once: the rejected cells are forgotten, and the count restarts
        assert first == FULL_TURN + 40 - 1 and nav.search.looked_again and not nav.rejected.any()
    else:
        assert first == FULL_TURN + 20 - 1 and nav.rejected.any()
    assert all(p.not_found for p in plans[first:]) and not any(p.stop for p in plans)
    nav.reset()
    assert not nav.search.looked_again  # once per episode
