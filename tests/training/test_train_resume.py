"""The train app end to end: exact resume, the debug preset through the CLI, torchrun."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from tests.helpers import train_overrides
from vla_gr import cli
from vla_gr.configs import load_config
from vla_gr.policy import load_policy, make_fake_batch
from vla_gr.train import train
from vla_gr.training.logger import read_metrics


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _final_weights(run: Path) -> dict[str, torch.Tensor]:
    latest = run / "checkpoints" / "latest"
    out = {f"eval.{k}": v for k, v in load_file(str(latest / "model.safetensors")).items()}
    train_state = load_file(str(latest / "training_state.safetensors"))
    return out | {k: v for k, v in train_state.items() if not k.startswith("rng.")}


def test_four_steps_equal_two_plus_resume_plus_two(tmp_path):
    """Flow-matching noise, shuffling, EMA, AdamW moments and an epoch boundary at the
    resume point (4 batches of 8 per epoch, accumulation 2) all continue exactly."""
    common = {
        "training.batch_size": 8,
        "training.grad_accum": 2,
        "training.warmup_steps": 0,
        "training.min_lr_ratio": 1.0,  # constant LR: the schedule cannot depend on `steps`
        "training.val_every": 2,
        "training.checkpoint_every": 2,
    }
    resolved, cfg = load_config(
        "config_debug",
        train_overrides(
            tmp_path, **common, **{"training.steps": 4, "training.run_name": "straight"}
        ),
    )
    train(cfg, resolved)
    resolved, cfg = load_config(
        "config_debug",
        train_overrides(tmp_path, **common | {"training.steps": 2, "training.run_name": "split"}),
    )
    train(cfg, resolved)
    resume = tmp_path / "runs" / "split" / "checkpoints" / "latest"
    resolved, cfg = load_config(
        "config_debug",
        train_overrides(
            tmp_path, **common, **{"training.steps": 4, "training.resume": str(resume)}
        ),
    )
    summary = train(cfg, resolved)
    assert summary["steps"] == 4 and Path(summary["run_dir"]).name == "split"
    straight = _final_weights(tmp_path / "runs" / "straight")
    split = _final_weights(tmp_path / "runs" / "split")
    assert straight.keys() == split.keys()
    for name, value in straight.items():
        assert torch.equal(value, split[name]), name
    state = json.loads((resume / "trainer_state.json").read_text())
    assert state["step"] == 4 and state["epoch"] == 1
    rows = read_metrics(resume.parent.parent / "metrics.jsonl")
    assert [r["step"] for r in rows if "train/loss" in r] == [1, 2, 3, 4]


def test_debug_preset_trains_and_resumes_through_the_cli(tmp_path):
    args = train_overrides(tmp_path, **{"training.run_name": "cli", "logging.tensorboard": "true"})
    done = subprocess.run(
        [sys.executable, "-m", "vla_gr.train", "--config-name", "config_debug", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    run = tmp_path / "runs" / "cli"
    assert (run / "config.yaml").is_file() and list((run / "tensorboard").glob("events.*"))
    assert (run / "checkpoints" / "best").resolve().name == "step_00000002"
    policy = load_policy(run / "checkpoints" / "best")
    saved = load_file(str(run / "checkpoints" / "best" / "model.safetensors"))
    assert all(torch.equal(v, saved[k]) for k, v in policy.state_dict().items())
    assert policy.predict_action_chunk(make_fake_batch(policy.config, 2)).shape == (2, 8, 3)
    resume = run / "checkpoints" / "latest"
    code = cli.main(
        [
            "train",
            "--config-name",
            "config_debug",
            *args,
            f"training.resume={resume}",
            "training.steps=3",
        ]
    )
    assert code == 0
    assert (run / "checkpoints" / "latest").resolve().name == "step_00000003"
    steps = [r["step"] for r in read_metrics(run / "metrics.jsonl")]
    assert sorted(set(steps)) == [1, 2, 3]
    # A checkpoint of another model is refused before any work, naming the key.
    code = cli.main(
        [
            "train",
            "--config-name",
            "config_debug",
            *args,
            f"training.resume={resume}",
            "training.steps=5",
            "model.encoders.dim=64",
        ]
    )
    assert code == 2
    assert (run / "checkpoints" / "latest").resolve().name == "step_00000003"


@pytest.mark.slow
def test_torchrun_two_cpu_processes_train_the_debug_preset(tmp_path):
    """The same script under ``torchrun --nproc_per_node=2`` (gloo on CPU)."""
    args = train_overrides(tmp_path, **{"training.run_name": "ddp", "training.steps": 3})
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--nproc_per_node=2",
            f"--master_port={_free_port()}",
            "-m",
            "vla_gr.train",
            "--config-name",
            "config_debug",
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    latest = tmp_path / "runs" / "ddp" / "checkpoints" / "latest"
    state = json.loads((latest / "trainer_state.json").read_text())
    assert state["world_size"] == 2 and state["step"] == 3 and len(state["rng"]) == 2
