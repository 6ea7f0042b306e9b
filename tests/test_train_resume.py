"""End to end: exact resume, the debug preset through the CLI, configs that validate."""

from __future__ import annotations

import importlib.util
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from vla_gr import cli
from vla_gr.configs import ConfigError, load_config
from vla_gr.policy import VLAGRPolicy, make_fake_batch
from vla_gr.train import train

CONFIG_DIR = Path(__file__).resolve().parents[1] / "src" / "vla_gr" / "configs"


def _overrides(tmp: Path, **extra) -> list[str]:
    base = {
        "training.dataset": str(tmp / "syn.zarr"),
        "training.output_dir": str(tmp / "runs"),
        "logging.tensorboard": "false",
    }
    base.update(extra)
    return [f"{k}={v}" for k, v in base.items()]


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
        _overrides(tmp_path, **common, **{"training.steps": 4, "training.run_name": "straight"}),
    )
    train(cfg, resolved)
    resolved, cfg = load_config(
        "config_debug",
        _overrides(tmp_path, **common, **{"training.steps": 2, "training.run_name": "split"}),
    )
    train(cfg, resolved)
    resume = tmp_path / "runs" / "split" / "checkpoints" / "latest"
    resolved, cfg = load_config(
        "config_debug",
        _overrides(tmp_path, **common, **{"training.steps": 4, "training.resume": str(resume)}),
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
    rows = [
        json.loads(x) for x in (resume.parent.parent / "metrics.jsonl").read_text().split("\n") if x
    ]
    assert [r["step"] for r in rows if "train/loss" in r] == [1, 2, 3, 4]


def test_debug_preset_trains_and_resumes_through_the_cli(tmp_path):
    args = _overrides(tmp_path, **{"training.run_name": "cli", "logging.tensorboard": "true"})
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
    policy = VLAGRPolicy.from_pretrained(run / "checkpoints" / "best")
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
    steps = [json.loads(x)["step"] for x in (run / "metrics.jsonl").read_text().split("\n") if x]
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
            "model.dim=64",
        ]
    )
    assert code == 2
    assert (run / "checkpoints" / "latest").resolve().name == "step_00000003"


@pytest.mark.slow
def test_torchrun_two_cpu_processes_train_the_debug_preset(tmp_path):
    """The same script under ``torchrun --nproc_per_node=2`` (gloo on CPU)."""
    args = _overrides(tmp_path, **{"training.run_name": "ddp", "training.steps": 3})
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


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIG_DIR.glob("config_*.yaml")))
def test_every_shipped_config_composes_and_validates(name):
    resolved, cfg = load_config(name)
    assert cfg.model.image_size == cfg.env.image_size
    assert cfg.training.batch_size > 0 and cfg.model.n_action_steps <= cfg.model.horizon


def test_recipe_specifics():
    _, rtx = load_config("config_rtx4060")
    assert rtx.training.amp == "fp16" and rtx.model.gradient_checkpointing
    assert rtx.training.batch_size * rtx.training.grad_accum == 32
    _, server = load_config("config_server")
    assert server.training.amp == "bf16" and server.training.compile
    assert server.training.ddp_backend == "nccl"


@pytest.mark.parametrize("method", ["lora", "oft", "adapter"])
def test_seed_overrides_work_verbatim(method):
    _, cfg = load_config(
        "config_rtx4060",
        [
            "model.peft.enabled=true",
            f"model.peft.method={method}",
            "model.peft.lora_rank=4",
            "training.resume=runs/x/checkpoints/latest",
        ],
    )
    assert cfg.model.peft.enabled and cfg.model.peft.method == method
    assert cfg.model.peft.lora_rank == 4 and cfg.training.resume.endswith("latest")


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("training.amp=fp8", "training.amp"),
        ("model.peft.method=prefix", "model.peft.method"),
        ("training.grad_accum=0", "training.grad_accum"),
        ("model.n_action_steps=99", "model.n_action_steps"),
        ("model.sampler=ddim", "model.sampler"),
    ],
)
def test_invalid_values_fail_naming_the_key(override, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        load_config("config_cpu", [override])


@pytest.mark.parametrize("override", ["training.learning_rate=1", "model.peft.rnk=4"])
def test_unknown_keys_fail_naming_the_key(override):
    with pytest.raises(ConfigError, match=override.split("=")[0]):
        load_config("config_cpu", [override])


@pytest.mark.skipif(importlib.util.find_spec("wandb") is not None, reason="wandb installed")
def test_wandb_enabled_without_wandb_is_a_clear_error():
    with pytest.raises(ValueError, match="wandb.*not installed"):
        load_config("config_cpu", ["logging.wandb.enabled=true"])
