"""The train app when a run is resumed twice, finished, pointed at a run folder or at no data."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import pytest
import torch

from tests.helpers import train_overrides
from vla_gr import checkpoint as ckpt
from vla_gr import cli
from vla_gr.configs import load_config
from vla_gr.train import train
from vla_gr.training.logger import read_metrics


def _args(tmp: Path, **extra) -> list[str]:
    return train_overrides(tmp, **{"training.run_name": "r", **extra})


def _train(tmp: Path, **extra) -> dict:
    resolved, cfg = load_config("config_debug", _args(tmp, **extra))
    return train(cfg, resolved)


def _rows(run: Path) -> list[dict]:
    return read_metrics(run / "metrics.jsonl")


def test_resume_from_an_earlier_checkpoint_logs_each_step_once(tmp_path):
    """Steps after the resumed checkpoint were logged by the first run (as if it was killed
    before its next checkpoint); the resumed run replaces those rows instead of repeating them."""
    _train(tmp_path, **{"training.steps": 3, "training.checkpoint_every": 2})
    run = tmp_path / "runs" / "r"
    first = _rows(run)
    resume = run / "checkpoints" / "step_00000002"
    _train(tmp_path, **{"training.steps": 3, "training.resume": str(resume)})
    rows = _rows(run)
    for key in ("train/loss", "val/loss"):
        steps = [r["step"] for r in rows if key in r]
        assert steps == sorted(set(steps)), (key, steps)
    assert [r["step"] for r in rows if "train/loss" in r] == [1, 2, 3]
    assert rows[:3] == first[:3]  # the rows up to the checkpoint are kept as they were
    assert rows[-1]["time"] > first[-1]["time"]  # step 3 comes from the resumed run


def test_resuming_a_finished_run_says_so_and_trains_nothing(tmp_path, caplog):
    _train(tmp_path)  # config_debug: 2 steps
    run = tmp_path / "runs" / "r"
    before = (run / "metrics.jsonl").read_text()
    latest = run / "checkpoints" / "latest"
    caplog.set_level(logging.INFO, logger="vla_gr")
    args = _args(tmp_path, **{"training.resume": str(latest)})
    assert cli.main(["train", "--config-name", "config_debug", *args]) == 0
    assert "already finished at step 2" in caplog.text
    assert "nan" not in caplog.text.lower()
    assert (run / "metrics.jsonl").read_text() == before
    assert latest.resolve().name == "step_00000002"
    summary = _train(tmp_path, **{"training.resume": str(latest)})
    assert summary["steps"] == 2
    assert all(not (isinstance(v, float) and math.isnan(v)) for v in summary.values()), summary


def test_resume_from_a_run_folder_suggests_its_latest_checkpoint(tmp_path, caplog):
    run = tmp_path / "runs" / "old"
    ckpt.save_checkpoint(run / "checkpoints", 1, {"w": torch.zeros(1)}, {"step": 1}, "a: 1\n")
    args = _args(tmp_path, **{"training.resume": str(run)})
    assert cli.main(["train", "--config-name", "config_debug", *args]) == 2
    assert f"did you mean {run / 'checkpoints' / 'latest'}?" in caplog.text


@pytest.mark.parametrize(
    ("key", "value", "named"),
    [
        ("training.if_missing", "error", "syn.zarr"),  # no dataset
        ("training.init_from", "nope/checkpoints/best", "nope"),  # no init checkpoint
    ],
)
def test_a_failed_set_up_leaves_no_run_folder(tmp_path, caplog, key, value, named):
    args = _args(tmp_path, **{key: value})
    assert cli.main(["train", "--config-name", "config_debug", *args]) == 2
    assert "does not exist" in caplog.text and named in caplog.text
    assert not (tmp_path / "runs").exists()
