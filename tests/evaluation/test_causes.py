"""Failure causes from an episode's record, and metrics.json from rows (pure functions)."""

from __future__ import annotations

import numpy as np
import pytest

from vla_gr.envs import DECLARED_OUTCOMES
from vla_gr.evaluation.causes import (
    CAUSES,
    REJECTED_GOAL_KINDS,
    WRONG_STOP_KINDS,
    CauseThresholds,
    failure_cause,
    is_stuck,
    rejected_goal_kind,
    wrong_stop_kind,
)
from vla_gr.evaluation.summary import (
    MISMATCHES_LISTED,
    cause_counts,
    declared_counts,
    episode_description,
    latency,
    not_understood_count,
    overall,
    reading_mismatches,
    readings,
    rejected_goal_counts,
    without_timing,
    wrong_stop_counts,
)

TH = CauseThresholds(success_distance=1.0, goal_seen_pixels=10, stuck_steps=5, stuck_radius=0.3)


def line(n: int, step: float = 0.2) -> np.ndarray:
    return np.stack([np.arange(n + 1) * step, np.zeros(n + 1)], axis=1)  # (n + 1, 2)


def test_a_success_has_no_cause():
    assert failure_cause(True, True, line(3), [0, 50], [0.2], TH) is None


def test_stop_within_success_distance_of_a_distractor_is_told_apart():
    assert failure_cause(False, True, line(3), [0], [3.0, 0.9], TH) == "stopped_at_distractor"
    assert failure_cause(False, True, line(3), [0], [3.0, 1.1], TH) == "stopped_elsewhere"
    assert failure_cause(False, True, line(3), [0], [], TH) == "stopped_elsewhere"


def test_stuck_needs_the_whole_last_window_inside_the_radius():
    moving = line(20, step=0.5)
    still_end = np.concatenate([moving, np.repeat(moving[-1:], 5, axis=0)])  # last 5 moves: 0
    assert is_stuck(still_end, 5, 0.3)
    assert not is_stuck(still_end, 6, 0.3)  # the window reaches back to a moving step
    assert not is_stuck(moving, 5, 0.3)
    assert not is_stuck(moving[:4], 5, 0.3)  # shorter than the window
    spin = np.zeros((30, 2)) + np.random.default_rng(0).normal(0, 0.01, (30, 2))
    assert failure_cause(False, False, spin, [500] * 30, [], TH) == "stuck"  # before "seen"


def test_timeouts_split_on_the_largest_goal_pixel_count():
    xy = line(30)
    assert failure_cause(False, False, xy, [0, 9, 3], [], TH) == "timeout_goal_never_seen"
    assert failure_cause(False, False, xy, [0, 10, 3], [], TH) == "timeout_goal_seen"
    assert failure_cause(False, False, xy, [-1, -1], [], TH) == "timeout_goal_never_seen"


def _row(success, cause, collisions, steps, latency_ms):
    m = dict(success=success, spl=0.5 * success, soft_spl=0.3, collision_rate=collisions / steps)
    m.update(path_length=2.0, distance_to_goal=1.5, collisions=collisions, steps=steps)
    return {"metrics": m, "cause": cause, "latency_ms": {"decision": latency_ms}}


def test_summary_counts_causes_shares_and_latency_percentiles():
    rows = [
        _row(1.0, None, 0, 10, [1.0] * 10),
        _row(0.0, "stuck", 2, 20, [3.0] * 20),
        _row(0.0, "stuck", 0, 10, [2.0] * 10),
    ]
    counts = cause_counts(rows)
    assert set(counts) == set(CAUSES) and counts["stuck"] == 2 and sum(counts.values()) == 2
    out = overall(rows)
    assert out["success"] == pytest.approx(1 / 3)
    assert out["collision_episode_share"] == pytest.approx(1 / 3)
    assert out["steps"] == pytest.approx(40 / 3)
    lat = latency(rows)["decision"]
    assert lat["calls"] == 40 and lat["p50"] == 2.5 and lat["p99"] == 3.0
    assert without_timing({"a": 1, "latency_ms": {}, "timing": {}}) == {"a": 1}


def test_a_wrong_stop_is_named_by_what_it_stopped_next_to():
    goal = {"category": "chair", "color": "red"}
    assert wrong_stop_kind(goal, {"category": "chair", "color": "blue"}) == "same_category"
    assert wrong_stop_kind(goal, {"category": "chair", "color": "red"}) == "same_category"
    assert wrong_stop_kind(goal, {"category": "table", "color": "red"}) == "same_colour"
    assert wrong_stop_kind(goal, {"category": "table", "color": "blue"}) == "other_object"
    rows = [{"wrong_stop": "same_colour"}, {"wrong_stop": None}, {}, {"wrong_stop": "same_colour"}]
    counts = wrong_stop_counts(rows)  # rows of older runs have no "wrong_stop"
    assert list(counts) == list(WRONG_STOP_KINDS) and counts["same_colour"] == 2
    assert sum(counts.values()) == 2


def test_a_rejected_goal_is_named_by_the_object_it_lay_on():
    goal = {"instance_id": 7, "category": "chair"}
    on = {"instance_id": 7, "category": "chair", "distance": 0.2}
    assert rejected_goal_kind(goal, on, 0.5) == "goal"
    assert rejected_goal_kind(goal, {**on, "distance": 0.6}, 0.5) == "other_object"  # nothing
    assert rejected_goal_kind(goal, {**on, "instance_id": 8}, 0.5) == "same_category"
    assert rejected_goal_kind(goal, {**on, "instance_id": 8, "category": "bed"}, 0.5) == (
        "other_object"
    )


def test_rejected_goals_are_counted_by_reason_and_the_failures_they_preceded():
    def rejected(*pairs):
        return [{"reason": why, "kind": kind} for why, kind in pairs]

    rows = [
        {"cause": "stuck", "rejected_goals": rejected(("trap", "goal"), ("room", "goal"))},
        {"cause": None, "rejected_goals": rejected(("room", "same_category"))},
        {"cause": "timeout_goal_seen", "rejected_goals": rejected(("verify", "other_object"))},
        {"cause": "stuck"},  # a row of an older run
    ]
    counts = rejected_goal_counts(rows)
    assert list(counts) == ["room", "trap", "verify", "episodes_failed_after_rejecting_the_goal"]
    assert counts["room"] == {"goal": 1, "same_category": 1, "other_object": 0}
    assert list(counts["trap"]) == list(REJECTED_GOAL_KINDS) and counts["trap"]["goal"] == 1
    assert counts["episodes_failed_after_rejecting_the_goal"] == 1  # the success does not count
    assert rejected_goal_counts([{"cause": None}]) == {}


def test_a_declared_outcome_is_the_cause_and_comes_before_the_others():
    xy = np.zeros((30, 2))  # standing still: "stuck" without the declaration
    assert set(DECLARED_OUTCOMES) <= set(CAUSES)
    for outcome in DECLARED_OUTCOMES:
        assert failure_cause(False, False, xy, [500], [0.2], TH, declared=outcome) == outcome
    assert failure_cause(False, False, xy, [500], [0.2], TH) == "stuck"
    with pytest.raises(ValueError, match="valid: not_understood, not_found"):
        failure_cause(False, False, xy, [0], [], TH, declared="lost")


def _reading(understood=True, **fields) -> dict:
    base = dict.fromkeys(("category", "color", "room", "anchor"))
    return {
        **base,
        **fields,
        "relation": None,
        "confidence": {},
        "unknown": [],
        "understood": understood,
        "reason": None if understood else "no goal named",
    }


def _read_row(index, instruction, reading, description=None, declared=None) -> dict:
    spec = {"instruction": instruction}
    if description is not None:
        spec["description"] = description
    return {"episode_index": index, "spec": spec, "reading": reading, "declared": declared}


def test_declared_outcomes_and_requests_not_understood_are_counted():
    rows = [
        _read_row(0, "find the piano", _reading(False), declared="not_understood"),
        _read_row(1, "find the red chair", _reading(category="chair", color="red")),
        _read_row(2, "find the sofa", _reading(category="sofa"), declared="not_found"),
        _read_row(3, "the chair that isn't red", _reading(False), declared="not_understood"),
        {"episode_index": 4, "spec": {"instruction": "find the bed"}},  # an older run's row
        _read_row(5, "find the bed", None),  # an agent without a reader
    ]
    assert declared_counts(rows) == {"not_understood": 2, "not_found": 1}
    assert list(declared_counts(rows[4:])) == list(DECLARED_OUTCOMES)
    assert sum(declared_counts(rows[4:]).values()) == 0
    assert [r["episode_index"] for r in readings(rows)] == [0, 1, 2, 3]
    assert not_understood_count(rows) == 2 and not_understood_count(rows[4:]) == 0


def test_an_episodes_description_is_its_own_else_what_its_instruction_says():
    fields = {"category": "chair", "color": "red", "room": None, "near": "tv_monitor"}
    said = {"instruction": "that red seat by the telly", "description": fields}
    want = {"category": "chair", "color": "red", "room": None, "anchor": "tv_monitor"}
    assert episode_description(said) == want
    generated = {"instruction": "find the blue sofa in the living room next to the plant"}
    assert episode_description(generated) == {
        "category": "sofa",
        "color": "blue",
        "room": "living_room",
        "anchor": "plant",
    }
    assert episode_description({"instruction": "bring me the piano"}) is None
    assert episode_description({"instruction": "x", "description": None}) is None


def test_readings_that_differ_from_the_description_are_listed():
    red_chair = {"category": "chair", "color": "red", "room": None, "near": None}
    rows = [
        _read_row(0, "find the red chair", _reading(category="chair", color="red")),  # agrees
        _read_row(1, "the red seat", _reading(category="chair"), red_chair),  # no colour
        _read_row(2, "find the red chair", _reading(category="chair", color="blue")),
        _read_row(3, "bring me the piano", _reading(False)),  # no description: not compared
        _read_row(4, "the chair that isn't red", _reading(False), red_chair),
        _read_row(5, "find the bed near the tv", _reading(category="bed", anchor="tv_monitor")),
        _read_row(6, "find the bed near the tv", _reading(category="bed", anchor="plant")),
        _read_row(7, "find the red chair", None),  # no reading
    ]
    out = reading_mismatches(rows)
    assert out["episodes"] == 4
    assert [m["episode"] for m in out["listed"]] == [1, 2, 4, 6]
    first = out["listed"][0]
    assert first["request"] == "the red seat"
    assert first["reading"] == {
        "category": "chair",
        "color": None,
        "room": None,
        "anchor": None,
        "understood": True,
    }
    assert first["description"] == {
        "category": "chair",
        "color": "red",
        "room": None,
        "anchor": None,
    }
    assert out["listed"][2]["reading"]["understood"] is False
    assert out["listed"][3]["description"]["anchor"] == "tv_monitor"
    limited = reading_mismatches(rows, limit=2)
    assert limited["episodes"] == 4 and len(limited["listed"]) == 2
    many = [_read_row(i, "find the sofa", _reading(category="bed")) for i in range(25)]
    assert len(reading_mismatches(many)["listed"]) == MISMATCHES_LISTED == 20


def test_the_kind_of_a_hand_written_request_comes_from_its_description():
    from vla_gr.evaluation.runner import instruction_kind

    said = "yo robot, the couch by the telly pls"
    assert instruction_kind(said) == "category"  # the generator's words are not in it
    fields = {"category": "sofa", "color": None, "room": None, "near": "tv_monitor"}
    assert instruction_kind(said, fields) == "relation"
    assert instruction_kind("find the red chair in the kitchen") == "room"
