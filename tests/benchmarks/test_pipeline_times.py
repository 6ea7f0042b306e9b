"""``benchmarks/pipeline_times.py``: a stage is done, running or not started by its records."""

import importlib.util
import json
from pathlib import Path

from vla_gr.configs import load_config

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "pipeline_times.py"
_spec = importlib.util.spec_from_file_location("pipeline_times", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_rows_follow_the_stage_records(tmp_path):
    _, cfg = load_config("recipe_debug", [f"pipeline.output_dir={tmp_path}"])
    (tmp_path / "expert").mkdir()
    attempts = [{"started": 0.0, "seconds": 60.0}, {"started": 90.0, "seconds": 30.0}]
    record = {"seconds": 90.0, "attempts": attempts}
    (tmp_path / "expert" / "stage.json").write_text(json.dumps(record))
    (tmp_path / "more").mkdir()
    (tmp_path / "more" / "started.json").write_text("{}")
    rows = bench.stage_rows(cfg)
    assert rows[0] == {"stage": "expert", "kind": "collect", "state": "done", "seconds": 90.0,
                       "attempts": 2}  # fmt: skip
    assert rows[1]["state"] == "running or interrupted"
    assert {r["state"] for r in rows[2:]} == {"not started"}
    assert "1 of 9 stages done, 1.5 min" in bench.table(rows)
