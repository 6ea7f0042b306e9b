"""metrics.jsonl on resume: rows past the resumed step (and a line torn by a kill) go."""

from __future__ import annotations

import json

from vla_gr.training.logger import MetricsLogger, drop_rows_after, read_metrics


def test_drop_rows_after_keeps_earlier_rows_and_removes_a_torn_line(tmp_path):
    path = tmp_path / "metrics.jsonl"
    rows = [{"step": s, "train/loss": 1.0 / s} for s in (1, 2, 2, 3, 4)]
    path.write_text("".join(json.dumps(r) + "\n" for r in rows) + '{"step": 5, "train/lo')
    assert drop_rows_after(path, 2) == 3  # steps 3, 4 and the torn step-5 line
    assert read_metrics(path) == rows[:3]
    assert drop_rows_after(path, 2) == 0 and read_metrics(path) == rows[:3]


def test_a_resumed_logger_appends_after_the_resumed_step(tmp_path):
    logger = MetricsLogger(tmp_path, tensorboard=False)
    for step in (1, 2, 3):
        logger.log(step, {"train/loss": float(step)})
    logger.close()
    logger = MetricsLogger(tmp_path, tensorboard=False, resume_step=2)
    logger.log(3, {"train/loss": 30.0})
    logger.close()
    rows = read_metrics(tmp_path / "metrics.jsonl")
    assert [(r["step"], r["train/loss"]) for r in rows] == [(1, 1.0), (2, 2.0), (3, 30.0)]
