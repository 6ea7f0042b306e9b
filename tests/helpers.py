"""Tiny models and batches shared by the training tests."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from vla_gr.configs.model_schema import ModelConfig
from vla_gr.core.diffusion_policy import HeadConfig
from vla_gr.core.encoders import EncodersConfig
from vla_gr.policy import NavigationPolicy, make_fake_batch, make_policy


def tiny_model_config(**overrides) -> ModelConfig:
    """A ~30 k-parameter agent on 16x16 images; deterministic L1 head unless overridden.

    ``overrides`` are flat: each key goes to the model layout, ``model.encoders`` or
    ``model.head``, whichever has it.
    """
    layout = dict(image_size=16, n_obs_steps=2, horizon=4, n_action_steps=2, agent="end_to_end")
    encoders = dict(
        dim=16,
        vision_channels=[8],
        vision_tokens=1,
        text_encoder="hashed",
        text_buckets=64,
        pose_hidden=8,
        fusion_layers=1,
        fusion_heads=2,
    )
    head = dict(hidden_dim=16, num_layers=1, num_heads=2, objective="l1")
    encoder_keys = {f.name for f in dataclasses.fields(EncodersConfig)}
    for key, value in overrides.items():
        if key in encoder_keys:
            encoders[key] = value
        elif key in {f.name for f in dataclasses.fields(ModelConfig)}:
            layout[key] = value
        else:
            head[key] = value
    return ModelConfig(**layout, encoders=EncodersConfig(**encoders), head=HeadConfig(**head))


def tiny_policy(seed: int = 0, **overrides) -> NavigationPolicy:
    """The tiny model config's agent (the end-to-end policy unless ``agent=`` says)."""
    torch.manual_seed(seed)
    return make_policy(tiny_model_config(**overrides))


def split_batch(batch: dict, parts: int) -> list[dict]:
    """Split a batch along B into ``parts`` equal micro-batches."""
    B = len(batch["instruction"])
    step = B // parts
    out = []
    for i in range(parts):
        sl = slice(i * step, (i + 1) * step)
        out.append({k: v[sl] for k, v in batch.items()})
    return out


def fake_batch(config: ModelConfig, batch_size: int, seed: int = 0) -> dict:
    return make_fake_batch(config, batch_size, seed)


def replace(cfg, **sections):
    """``dataclasses.replace`` on sections: replace(cfg, training={"steps": 4})."""
    updates = {k: dataclasses.replace(getattr(cfg, k), **v) for k, v in sections.items()}
    return dataclasses.replace(cfg, **updates)


def train_overrides(tmp: Path, **extra) -> list[str]:
    """Hydra overrides for a training run under ``tmp`` (a synthetic store, no TensorBoard)."""
    base = {
        "training.dataset": str(tmp / "syn.zarr"),
        "training.output_dir": str(tmp / "runs"),
        "logging.tensorboard": "false",
    }
    return [f"{k}={v}" for k, v in (base | extra).items()]
