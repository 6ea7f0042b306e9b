"""metrics.json and the report on absent-object episodes: they never enter SR / SPL, the
breakdowns or the failure causes; their own block counts right "not found" declarations,
false STOPs, timeouts and the steps to declare. A "not found" on a normal episode is a failure
and is counted."""

from __future__ import annotations

import pytest

from vla_gr.evaluation.report import absent_lines, table_row
from vla_gr.evaluation.summary import absent_objects, summarize_rows


def _row(index, *, absent=False, success=0.0, spl=0.0, steps=100, cause=None, stopped=False,
         declared=None, wrong_stop=None, rooms=1) -> dict:  # fmt: skip
    metrics = {
        "success": success, "spl": spl, "soft_spl": spl, "distance_to_goal": 2.0,
        "collisions": 0, "collision_rate": 0.0, "path_length": 3.0,
        "geodesic_start_distance": 0.0 if absent else 2.0, "steps": steps,
    }  # fmt: skip
    return {
        "episode_index": index,
        "spec": {"instruction": "find the red chair", **({"absent": True} if absent else {})},
        "metrics": metrics,
        "stopped": stopped,
        "cause": cause,
        "declared": declared,
        "declared_not_found": declared == "not_found",
        "absent": absent,
        "reading": None,
        "num_rooms": rooms,
        "goal_category": "chair",
        "instruction_kind": "colour",
        "wrong_stop": wrong_stop,
        "rejected_goals": [],
        "latency_ms": {"decision": [1.0]},
        "parameters": {"total": 1},
        "agent": {},
    }


ROWS = [
    _row(0, success=1.0, spl=0.8, steps=100, stopped=True, rooms=2),
    _row(1, steps=400, cause="not_found", declared="not_found"),  # a false "not found"
    _row(2, steps=200, cause="stopped_elsewhere", stopped=True, wrong_stop="other_object"),
    _row(3, steps=1000, cause="timeout_goal_never_seen"),
    _row(4, absent=True, steps=300, cause="not_found", declared="not_found"),
    _row(5, absent=True, steps=500, cause="not_found", declared="not_found"),
    _row(6, absent=True, steps=700, cause="not_found", declared="not_found"),
    _row(
        7,
        absent=True,
        steps=250,
        cause="stopped_at_distractor",
        stopped=True,
        wrong_stop="same_category",
    ),  # a false STOP, next to a chair of another colour
    _row(8, absent=True, steps=1000, cause="timeout_goal_never_seen"),
]


def test_absent_episodes_are_counted_apart_and_never_enter_sr_or_spl():
    m = summarize_rows(ROWS, {"agent": "checkpoint"}, seconds=1.0, workers=1)
    assert m["metrics"]["episodes"] == 4  # the normal episodes only
    assert m["metrics"]["success"] == pytest.approx(1 / 4)
    assert m["metrics"]["spl"] == pytest.approx(0.8 / 4)
    assert m["metrics"]["steps"] == pytest.approx((100 + 400 + 200 + 1000) / 4)
    assert m["breakdowns"]["num_rooms"] == {
        "1": {"episodes": 3, "success": 0.0, "spl": 0.0},
        "2": {"episodes": 1, "success": 1.0, "spl": 0.8},
    }
    causes = {k: v for k, v in m["failure_causes"].items() if v}
    assert causes == {"not_found": 1, "stopped_elsewhere": 1, "timeout_goal_never_seen": 1}
    assert m["declared"] == {"not_understood": 0, "not_found": 1}  # on normal episodes: a failure
    assert {k: v for k, v in m["wrong_stops"].items() if v} == {"other_object": 1}
    assert m["absent_objects"] == {
        "episodes": 5,
        "declared_not_found": 3,
        "false_stops": 1,
        "timeouts": 1,
        "not_understood": 0,
        "declared_not_found_rate": 0.6,
        "false_stop_rate": 0.2,
        "steps_to_declare": {"median": 500.0, "mean": 500.0, "max": 700.0},
        "false_stops_by_kind": {"same_category": 1, "same_colour": 0, "other_object": 0},
    }


def test_the_report_shows_the_block_and_a_run_without_absent_episodes_has_none():
    m = summarize_rows(ROWS, {"agent": "checkpoint"}, seconds=1.0, workers=1)
    text = "\n".join(absent_lines(m))
    assert "## Absent objects" in text and "5 episode(s)" in text
    assert "| 3 (60.0%) | 1 (20.0%) | 1 | 0 | 500 |" in text
    normal = summarize_rows(ROWS[:4], {"agent": "checkpoint"}, seconds=1.0, workers=1)
    assert normal["absent_objects"]["episodes"] == 0 and absent_lines(normal) == []
    assert normal["absent_objects"]["steps_to_declare"] is None
    assert normal["metrics"] == m["metrics"]  # the absent rows changed no normal figure


def test_a_run_of_absent_episodes_alone_has_no_sr_and_older_rows_are_normal():
    m = summarize_rows(ROWS[4:], {"agent": "checkpoint"}, seconds=1.0, workers=1)
    assert m["metrics"] == {"episodes": 0}
    assert table_row(m)["episodes"] == 0 and "success" not in table_row(m)
    assert sum(m["failure_causes"].values()) == 0
    older = [{k: v for k, v in r.items() if k not in ("absent", "declared_not_found")}
             for r in ROWS[:4]]  # fmt: skip
    assert absent_objects(older)["episodes"] == 0
