"""Recipe validation: every shipped config composes, bad keys and values fail naming the key
(``vla_gr.configs``: schema.py, training_schema.py; test_recipes.py checks the defaults)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

import vla_gr.configs
from vla_gr.configs import ConfigError, load_config

CONFIG_DIR = Path(vla_gr.configs.__file__).parent


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIG_DIR.glob("config_*.yaml")))
def test_every_shipped_config_composes_and_validates(name):
    resolved, cfg = load_config(name)
    assert cfg.model.image_size == cfg.env.image_size
    assert cfg.training.batch_size > 0 and cfg.model.n_action_steps <= cfg.model.horizon


def test_recipe_specifics():
    _, rtx = load_config("config_rtx4060")
    assert rtx.training.amp == "fp16" and rtx.training.gradient_checkpointing
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
        ("model.head.sampler=ddim", "model.head.sampler"),
        ("training.paraphrase_prob=1.5", "training.paraphrase_prob"),
        ("training.flip_prob=1.5", "training.flip_prob"),
        ("training.flip_prob=0.5", "training.flip_prob"),  # an end-to-end agent learns actions
    ],
)
def test_invalid_values_fail_naming_the_key(override, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        load_config("config_end_to_end", [override])


@pytest.mark.parametrize("override", ["training.learning_rate=1", "model.peft.rnk=4"])
def test_unknown_keys_fail_naming_the_key(override):
    with pytest.raises(ConfigError, match=override.split("=")[0]):
        load_config("config_end_to_end", [override])


@pytest.mark.skipif(importlib.util.find_spec("wandb") is not None, reason="wandb installed")
def test_wandb_enabled_without_wandb_is_a_clear_error():
    with pytest.raises(ValueError, match="wandb.*not installed"):
        load_config("config_cpu", ["logging.wandb.enabled=true"])


@pytest.mark.parametrize("metric", ["spl", "success"])
def test_best_metric_from_closed_loop_needs_eval_episodes(metric):
    with pytest.raises(ValueError, match=r"training\.best_metric.*training\.eval_episodes"):
        load_config("config_debug", [f"training.best_metric={metric}"])


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("training.best_metric=sr", "training.best_metric"),
        ("training.eval_episodes=-1", "training.eval_episodes"),
        ("training.eval_max_steps=0", "training.eval_max_steps"),
    ],
)
def test_invalid_eval_settings_fail_naming_the_key(override, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        load_config("config_debug", [override])


def test_eval_without_validation_period_is_refused():
    with pytest.raises(ValueError, match=r"training\.val_every"):
        load_config("config_debug", ["training.eval_episodes=2", "training.val_every=0"])
