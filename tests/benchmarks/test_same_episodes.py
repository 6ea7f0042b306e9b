"""``benchmarks/same_episodes.py``: one changed action, outcome or summary shows."""

import copy
import importlib.util
from pathlib import Path

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "same_episodes.py"
_spec = importlib.util.spec_from_file_location("same_episodes", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)
differences, fingerprint = bench.differences, bench.fingerprint

ROW = {
    "episode_index": 7,
    "episode_id": "val-000007",
    "metrics": {"success": 1.0, "spl": 0.5, "steps": 3},
    "stopped": True,
    "cause": None,
    "agent": {"goal_confidence": 1.0},
    "actions": [[0.5, 0.0, -1.0], [0.5, 0.1, -1.0], [0.0, 0.0, 1.0]],
    "trace": {"xy": [[0.0, 0.0], [0.05, 0.0]]},
    "latency_ms": {"decision": [1.0, 2.0, 3.0]},
}


def test_identical_rows_differ_in_nothing_and_timings_do_not_count():
    other = copy.deepcopy(ROW)
    other["latency_ms"]["decision"] = [9.0, 9.0, 9.0]
    assert differences([fingerprint(ROW)], [fingerprint(other)]) == {}


def test_one_action_one_metric_or_a_missing_episode_is_named():
    moved = copy.deepcopy(ROW)
    moved["actions"][1][1] = 0.1000001
    assert differences([fingerprint(ROW)], [fingerprint(moved)]) == {7: ["actions_sha256"]}
    worse = copy.deepcopy(ROW)
    worse["metrics"]["spl"], worse["agent"]["goal_confidence"] = 0.4, 0.9
    assert differences([fingerprint(ROW)], [fingerprint(worse)]) == {7: ["metrics", "agent"]}
    assert differences([fingerprint(ROW)], []) == {7: ["missing"]}
