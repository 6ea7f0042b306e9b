"""Training-time closed-loop validation: logged metrics, rollout videos in TensorBoard, `best`
by SPL, resume."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tests.helpers import train_overrides
from tests.training.test_logger import gif_frames, tensorboard_videos
from vla_gr import cli
from vla_gr.checkpoint import read_checkpoint
from vla_gr.evaluation.video import END_HOLD_SECONDS
from vla_gr.train import VIDEO_PANEL, VIDEO_STRIDE
from vla_gr.training.closed_loop import WORST, best_score, score_from_state
from vla_gr.training.logger import read_metrics

EVAL = ["training.eval_episodes=1", "training.best_metric=spl", "training.eval_max_steps=20",
        "training.eval_videos=1"]  # fmt: skip


def _args(tmp: Path) -> list[str]:
    return [
        *train_overrides(tmp, **{"training.run_name": "ev", "logging.tensorboard": "true"}),
        *EVAL,
    ]


def _records(run: Path) -> list[dict]:
    return read_metrics(run / "metrics.jsonl")


def test_debug_preset_logs_closed_loop_metrics_and_picks_best_by_spl(tmp_path):
    assert cli.main(["train", "--config-name", "config_debug", *_args(tmp_path)]) == 0
    run = tmp_path / "runs" / "ev"
    vals = [r for r in _records(run) if "val/spl" in r]
    assert [r["step"] for r in vals] == [2]  # val_every=2, steps=2
    for key in ("val/success", "val/spl", "val/soft_spl", "val/collision_rate", "val/loss"):
        assert 0.0 <= vals[0][key] < math.inf
    best = read_checkpoint(run / "checkpoints" / "best")
    assert (run / "checkpoints" / "best").resolve().name == "step_00000002"
    assert best.state["best_metric"] == "spl"
    assert best.state["best_score"] == pytest.approx([vals[0]["val/spl"], -vals[0]["val/loss"]])
    # The validated episode's video, read back from TensorBoard's event file.
    ((step, gif),) = tensorboard_videos(run)["val/episode_0"]
    assert step == 2 and gif.size[0] == 3 * VIDEO_PANEL and gif.size[1] > VIDEO_PANEL
    frames = gif_frames(gif)
    frame_ms = 1000 * VIDEO_STRIDE / 10  # the debug env's 10 Hz, every VIDEO_STRIDE-th step
    assert 2 <= len(frames) <= 1 + 20 / VIDEO_STRIDE + END_HOLD_SECONDS * 1000 / frame_ms
    assert frames[-1][1] >= END_HOLD_SECONDS * 1000  # the end held (identical frames merged)
    assert all(f.std() > 10 for f, _ in frames)  # pictures, not blank frames
    # Resume: the best score comes back from trainer_state.json and keeps being tracked.
    resume = run / "checkpoints" / "latest"
    code = cli.main(
        [
            "train",
            "--config-name",
            "config_debug",
            *_args(tmp_path),
            f"training.resume={resume}",
            "training.steps=4",
        ]
    )
    assert code == 0
    vals = [r for r in _records(run) if "val/spl" in r]
    assert [r["step"] for r in vals] == [2, 4]
    assert [s for s, _ in tensorboard_videos(run)["val/episode_0"]] == [2, 4]
    scores = [(r["val/spl"], -r["val/loss"]) for r in vals]
    latest = read_checkpoint(run / "checkpoints" / "latest").state
    assert latest["best_score"] == pytest.approx(list(max(scores)))
    picked = 2 if scores[0] >= scores[1] else 4
    assert (run / "checkpoints" / "best").resolve().name == f"step_{picked:08d}"


def test_best_score_orders_by_metric_then_lower_loss():
    evals = {"val/spl": 0.5, "val/success": 1.0}
    assert best_score("spl", 0.2, evals) > best_score("spl", 0.3, evals)  # tie -> lower loss
    assert best_score("spl", 9.0, evals) > best_score("spl", 0.1, {"val/spl": 0.4})
    assert best_score("val_loss", 0.1, {}) > best_score("val_loss", 0.2, evals)
    assert best_score("spl", math.nan, evals) > WORST  # no held-out loss: still comparable


def test_score_from_state_is_backward_compatible():
    assert score_from_state({"best_val_loss": 0.25}, "val_loss") == (-0.25, 0.0)
    assert score_from_state({"best_val_loss": 0.25}, "spl") == WORST
    state = {"best_metric": "spl", "best_score": [0.5, None], "best_val_loss": None}
    assert score_from_state(state, "spl") == (0.5, -math.inf)
    assert score_from_state(state, "success") == WORST
