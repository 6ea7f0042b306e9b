"""The navigator's goal checks: room, object category and a relation's anchor."""

import numpy as np
import pytest

from tests.agent.navigator.navigator_scenes import ROOM, make_nav, room_depth, wall_goal
from vla_gr.agent.navigator.config import GoalChecksConfig


def _checked_nav(**goal_checks):
    """A navigator that stops within 0.8 m of a confirmed goal, with ``goal_checks`` set."""
    return make_nav(look_around={"angle": 0.0}, approach={"stop_distance": 0.8},
                    goal_checks=goal_checks)  # fmt: skip


def test_the_room_check_rejects_a_goal_in_another_room_and_stops_in_the_right_one():
    near = (ROOM[1] - 0.6, 0.0, 0.0)  # 0.6 m from the wall the likelihood marks
    like = wall_goal(room_depth(near))

    def run(room_match, threshold=0.5, ticks=4):
        nav = _checked_nav(room_reject_threshold=threshold, room_ticks=2)
        depth = room_depth(near)
        plans = [
            nav.plan({"depth": depth, "pose": np.array(near, np.float32)}, like, 1.0, m)
            for m in room_match[:ticks]
        ]
        return nav, plans

    # confidently in another room: the goal is rejected on the tick it is confirmed and near
    nav, plans = run([0.1, 0.1, 0.1, 0.1])
    assert not any(p.stop for p in plans)
    assert nav.rejections == 1 and plans[1].mode == "explore" and nav.rejected.any()
    assert nav.rejection_log[0]["reason"] == "room"
    # the mean of the last room_ticks decides: one doubtful frame after a good one still stops
    nav, plans = run([0.9, 0.2])
    assert plans[1].stop and nav.rejections == 0
    assert nav.stop_evidence["room_match"] == pytest.approx(0.55)
    # below the threshold on the mean: rejected
    nav, plans = run([0.3, 0.2])
    assert not plans[1].stop and nav.rejections == 1
    # off (0): the same evidence stops
    nav, plans = run([0.1, 0.1], threshold=0.0)
    assert plans[1].stop and nav.rejections == 0


def test_the_room_map_keeps_a_goal_where_all_the_robot_saw_says_the_instructed_room():
    """Two doubtful ticks at the goal reject it unless the room map, from every tick that
    typed the robot's cell, believes the instructed room there at least ``room_map_keep``."""
    near, far = (ROOM[1] - 0.6, 0.0, 0.0), (ROOM[1] - 1.4, 0.0, 0.0)  # 0.8 m apart
    kitchen, bathroom = np.array([0.9, 0.1]), np.array([0.1, 0.9])
    search = {"enabled": True, "categories": ["chair"], "room_types": ["kitchen", "bathroom"],
              "presence": [[0.5, 0.5]], "room_share": [0.5, 0.5]}  # fmt: skip

    def run(before, keep, room="kitchen"):
        """6 ticks 1.4 m from the goal (beyond the stop distance) typing the place as
        ``before``, then ticks at 0.6 m whose room match is 0.1 (the classifier doubts the
        kitchen there): the first of them judges the goal."""
        nav = make_nav(look_around={"angle": 0.0}, approach={"stop_distance": 0.8},
                       goal_checks={"room_reject_threshold": 0.5, "room_ticks": 1,
                                    "room_map_keep": keep},
                       room_search=search)  # fmt: skip
        nav.set_search_goal("chair", room)
        plans = []
        for pose, match, probs in [(far, 0.9, before)] * 6 + [(near, 0.1, bathroom)] * 2:
            depth = room_depth(pose)
            obs = {"depth": depth, "pose": np.array(pose, np.float32)}
            plans.append(nav.plan(obs, wall_goal(depth), 1.0, match, room_probs=probs))
        return nav, plans

    # the map believes the kitchen there ((6 * 0.9 + 0.1) / 7 = 0.786): the goal is kept
    nav, plans = run(kitchen, keep=0.5)
    assert plans[6].stop and nav.rejections == 0
    assert nav.stop_evidence["room_belief"] == pytest.approx(5.5 / 7, abs=1e-4)
    assert nav.checks.room_map_kept == 2  # both ticks at the goal: the map overruled them
    # above the map's belief: rejected as without the map
    nav, plans = run(kitchen, keep=0.8)
    assert not plans[6].stop and nav.rejection_log[0]["reason"] == "room"
    # off (0): the last ticks alone decide
    nav, plans = run(kitchen, keep=0.0)
    assert not plans[-1].stop and nav.rejections == 1 and nav.checks.room_map_kept == 0
    # the map says bathroom too ((6 * 0.1 + 0.1) / 7 = 0.1): rejected
    nav, plans = run(bathroom, keep=0.5)
    assert not plans[-1].stop and nav.rejections == 1
    # no room named: the check has nothing to judge, the map no belief
    nav, plans = run(kitchen, keep=0.5, room=None)
    assert nav.room_belief is None


def test_the_object_check_rejects_a_goal_of_another_category_and_ignores_ticks_without_evidence():
    near = (ROOM[1] - 0.6, 0.0, 0.0)
    like = wall_goal(room_depth(near))

    def run(object_match, threshold=0.5):
        nav = _checked_nav(object_reject_threshold=threshold, object_ticks=2)
        depth = room_depth(near)
        pose = np.array(near, np.float32)
        plans = [nav.plan({"depth": depth, "pose": pose}, like, 1.0, 1.0, m) for m in object_match]
        return nav, plans

    # the goal pixels confidently show another category: rejected when confirmed and near
    nav, plans = run([0.1, 0.1])
    assert not any(p.stop for p in plans) and nav.rejections == 1 and nav.rejected.any()
    assert nav.rejection_log[0]["reason"] == "object"
    assert len(nav.checks.object_matches) == 0  # the rejected goal's evidence goes with it
    # the mean of the last object_ticks values with evidence decides
    nav, plans = run([0.9, 0.2])
    assert plans[1].stop and nav.stop_evidence["object_match"] == pytest.approx(0.55)
    nav, plans = run([0.3, 0.2])
    assert not plans[1].stop and nav.rejections == 1
    # ticks without evidence (None) neither count nor reject
    nav, plans = run([0.1, None, None][1:])
    assert plans[1].stop and nav.stop_evidence["object_match"] is None
    nav, plans = run([0.2, None])
    assert not plans[1].stop and nav.rejections == 1  # 0.2 is still the last evidence
    # off (0): the same evidence stops
    nav, plans = run([0.1, 0.1], threshold=0.0)
    assert plans[1].stop and nav.rejections == 0


def test_the_relation_check_rejects_a_goal_without_its_anchor_mapped_near():
    near = (ROOM[1] - 0.6, 0.0, 0.0)  # facing the +x wall, 0.6 m away
    depth = room_depth(near)
    like = wall_goal(depth)  # the goal: the central columns of the wall
    n = depth.shape[1]

    def anchor_at(cols):
        """The anchor on the wall pixels of ``cols``."""
        out = np.zeros_like(like)
        out[:, cols] = (like.sum(1) > 0)[:, None]  # the goal's wall rows
        return out

    beside = anchor_at(slice(n // 2 + 4, n // 2 + 8))  # right beside the goal
    apart = anchor_at(slice(n - 3, n))  # the wall's far right edge, about 0.5 m from it

    def run(anchor, distance=0.2):
        nav = _checked_nav(relation_distance=distance)
        pose = np.array(near, np.float32)
        plans = [nav.plan({"depth": depth, "pose": pose}, like, 1.0, 1.0, None, anchor)
                 for _ in range(2)]  # fmt: skip
        return nav, plans

    nav, plans = run(beside)
    assert plans[1].stop and nav.stop_evidence["anchor_distance"] <= 0.2
    nav, plans = run(apart)  # mapped, but farther than relation_distance
    assert not plans[1].stop and nav.rejections == 1
    assert nav.rejection_log[0]["reason"] == "relation"
    nav, plans = run(apart, distance=1.0)  # within a wider distance
    assert plans[1].stop and 0.2 < nav.stop_evidence["anchor_distance"] <= 1.0
    nav, plans = run(np.zeros_like(like))  # never seen
    assert not plans[1].stop and nav.rejections == 1
    nav, plans = run(None)  # the instruction names no anchor: no check
    assert plans[1].stop and nav.stop_evidence["anchor_distance"] is None
    nav, plans = run(np.zeros_like(like), distance=0.0)  # off: recorded, not acted on
    assert plans[1].stop and nav.stop_evidence["anchor_cells"] == 0


def test_an_anchor_read_on_the_goal_itself_is_not_its_anchor_when_the_anchor_must_outvote_it():
    near = (ROOM[1] - 0.6, 0.0, 0.0)  # facing the +x wall, 0.6 m away
    depth = room_depth(near)
    like = wall_goal(depth)  # the goal: columns n/2-3 .. n/2+2 of the wall
    n = depth.shape[1]
    on_goal = np.zeros_like(like)
    on_goal[:, n // 2 - 1 : n // 2 + 1] = like[:, n // 2 - 1 : n // 2 + 1]  # its own pixels
    beside = np.zeros_like(like)
    beside[:, n // 2 + 5 : n // 2 + 9] = (like.sum(1) > 0)[:, None]  # the wall right of it

    def run(anchor, outvote):
        nav = _checked_nav(relation_distance=0.2, anchor_outvotes_goal=outvote)
        pose = np.array(near, np.float32)
        plans = [nav.plan({"depth": depth, "pose": pose}, like, 1.0, 1.0, None, anchor)
                 for _ in range(2)]  # fmt: skip
        return nav, plans

    nav, plans = run(on_goal, outvote=False)  # counted as an anchor at distance 0
    assert plans[1].stop and nav.stop_evidence["anchor_distance"] == 0.0
    nav, plans = run(on_goal, outvote=True)  # the goal's cells stay the goal's: no anchor
    assert not plans[1].stop and nav.rejection_log[0]["reason"] == "relation"
    assert nav.rejections == 1
    nav, plans = run(beside, outvote=True)  # a real neighbour still counts
    assert plans[1].stop and nav.stop_evidence["anchor_distance"] <= 0.2
    assert nav.stop_evidence["anchor_cells"] > 0


@pytest.mark.parametrize(
    "overrides, key",
    [
        ({"room_reject_threshold": 1.5}, "room_reject_threshold"),
        ({"room_ticks": 0}, "room_ticks"),
        ({"room_map_keep": 1.2}, "room_map_keep"),
        ({"object_reject_threshold": -0.1}, "object_reject_threshold"),
        ({"object_ticks": 0}, "object_ticks"),
        ({"relation_distance": -1.0}, "relation_distance"),
        ({"anchor_ticks": -1}, "anchor_ticks"),
    ],
)
def test_room_check_settings_out_of_range_name_the_key(overrides, key):
    with pytest.raises(ValueError, match=rf"model\.navigator\.goal_checks\.{key}="):
        GoalChecksConfig(**overrides)


def test_a_goal_read_where_the_anchor_was_read_more_often_is_the_anchor_when_the_goal_yields():
    near = (ROOM[1] - 0.6, 0.0, 0.0)  # facing the +x wall, 0.6 m away
    depth = room_depth(near)
    like = wall_goal(depth)  # the goal head's pixels on the wall, and the segmenter's anchor

    def run(yields):
        nav = make_nav(
            look_around={"angle": 0.0},
            approach={"stop_distance": 0.8},
            confirmation={"visible_threshold": 0.5},
            goal_checks={"relation_distance": 1.0, "goal_yields_to_anchor": yields},
        )
        pose = np.array(near, np.float32)
        # the anchor is read there on three ticks, the goal on the last two (the first is
        # below confirmation.visible_threshold: no goal votes)
        plans = [nav.plan({"depth": depth, "pose": pose}, like, visible, 1.0, None, like)
                 for visible in (0.0, 1.0, 1.0)]  # fmt: skip
        return nav, plans

    nav, plans = run(yields=False)  # two goal ticks confirm it; the anchor is "right there"
    assert plans[2].stop and nav.stop_evidence["anchor_distance"] == 0.0
    nav, plans = run(yields=True)  # the anchor's cells: no goal to stop at
    assert not any(p.stop for p in plans) and not nav.committed
    assert not nav.checks.confirmed_goal(nav.goal_votes).any()
    assert nav.goal_votes.max() == 2  # the votes are kept: only the cells' owner changed


@pytest.mark.parametrize("anchor_ticks, stops", [(0, True), (3, True), (4, False)])
def test_an_anchor_needs_anchor_ticks_ticks_of_its_pixels(anchor_ticks, stops):
    near = (ROOM[1] - 0.6, 0.0, 0.0)  # facing the +x wall, 0.6 m away
    depth = room_depth(near)
    like = wall_goal(depth)
    n = depth.shape[1]
    beside = np.zeros_like(like)
    beside[:, n // 2 + 5 : n // 2 + 9] = (like.sum(1) > 0)[:, None]  # the wall right of it
    nav = make_nav(
        look_around={"angle": 0.0},
        approach={"stop_distance": 0.8},
        confirmation={"visible_threshold": 0.5},
        goal_checks={"relation_distance": 0.5, "anchor_ticks": anchor_ticks},
    )
    pose = np.array(near, np.float32)
    # the anchor is seen on three ticks; the goal votes on the last two, confirmed at the third
    plans = [nav.plan({"depth": depth, "pose": pose}, like, visible, 1.0, None, beside)
             for visible in (0.0, 1.0, 1.0)]  # fmt: skip
    assert plans[2].stop == stops and nav.rejections == (0 if stops else 1)
    if not stops:
        assert nav.rejection_log[0]["reason"] == "relation"
