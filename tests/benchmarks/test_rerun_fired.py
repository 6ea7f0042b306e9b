"""rerun_fired: the episodes a rule fired in, and the run put together without it."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from vla_gr.envs.episodes import load_episodes, sample_episode

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "rerun_fired.py"
_spec = importlib.util.spec_from_file_location("rerun_fired", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def _row(index: int, success: float, spl: float, reasons=()) -> dict:
    spec = sample_episode("val", index)
    return {
        "episode_id": spec.episode_id,
        "spec": spec.to_dict(),
        "metrics": {
            "success": success,
            "spl": spl,
            "soft_spl": spl,
            "collision_rate": 0.0,
            "path_length": 3.0,
            "distance_to_goal": 0.5 if success else 2.0,
        },  # fmt: skip
        "rejected_goals": [{"reason": r, "kind": "goal"} for r in reasons],
    }


def _write(folder: Path, rows) -> Path:
    folder.mkdir()
    (folder / "episodes.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    return folder


def test_the_fired_episodes_and_the_run_without_the_rule(tmp_path):
    on = _write(tmp_path / "on", [
        _row(0, 1.0, 0.8, ["room", "unreachable"]),  # won by the rule
        _row(1, 0.0, 0.0, ["unreachable"]),  # lost by it
        _row(2, 1.0, 0.6, ["room"]),  # the rule did not act: not rerun
        _row(3, 0.0, 0.0, ["unreachable"]),  # fails either way
    ])  # fmt: skip
    specs = bench.fired_specs(on, "unreachable")
    assert [s.episode_id for s in specs] == ["val-000000", "val-000001", "val-000003"]
    assert len(bench.fired_specs(on, "any")) == 4
    rows = [json.loads(line) for line in (on / "episodes.jsonl").read_text().splitlines()]
    rows[2]["agent"], rows[3]["agent"] = {"room_map_kept": 3}, {"room_map_kept": 0}
    _write(tmp_path / "kept", rows)  # the room map kept a goal in episode 2 only
    kept = bench.fired_specs(tmp_path / "kept", "room_map_kept")
    assert [s.episode_id for s in kept] == ["val-000002"]
    rows = [json.loads(line) for line in (on / "episodes.jsonl").read_text().splitlines()]
    rows[1]["declared"], rows[2]["declared"] = "not_found", "not_found"
    (tmp_path / "declared").mkdir()
    (tmp_path / "declared" / "episodes.jsonl").write_text("\n".join(map(json.dumps, rows)))
    declared = bench.fired_specs(tmp_path / "declared", "any", "not_found")
    assert [s.episode_id for s in declared] == ["val-000001", "val-000002"]
    bench.save_episodes(tmp_path / "fired.jsonl", specs)
    assert load_episodes(tmp_path / "fired.jsonl") == specs  # a file vla-gr eval runs
    off = _write(tmp_path / "off", [
        _row(0, 0.0, 0.0), _row(1, 1.0, 0.5), _row(3, 0.0, 0.0),
    ])  # fmt: skip
    m = bench.merge(on, off)
    assert (m["episodes"], m["rerun"]) == (4, 3)
    with_rule, without_rule = m["with_rule"], m["without_rule"]
    # (1 + 0 + 1 + 0) / 4, (.8 + .6) / 4; then (0 + 1 + 1 + 0) / 4, 1.1 / 4
    assert (with_rule["success"], with_rule["spl"]) == pytest.approx((0.5, 0.35))
    assert (without_rule["success"], without_rule["spl"]) == pytest.approx((0.5, 0.275))
    assert with_rule["episodes"] == without_rule["episodes"] == 4
    assert m["won"] == ["val-000000"] and m["lost"] == ["val-000001"]
    # rows rerun that the first run lacks: refused
    with pytest.raises(SystemExit, match="does not"):
        bench.merge(off, on)
