"""Inputs of the agent: environment observations -> policy frames, fake batches, PEFT."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import nn

from vla_gr.configs.model_schema import ModelConfig

__all__ = ["apply_peft", "as_instructions", "env_obs_to_frame", "make_fake_batch"]


def apply_peft(model: nn.Module, peft) -> nn.Module:
    """Apply ``model.peft`` (a :class:`PeftConfig`) in place when enabled; returns ``model``."""
    if not peft.enabled:
        return model
    from vla_gr.core import peft_modules

    targets = list(peft.target_modules)
    if peft.method == "lora":
        peft_modules.apply_lora_to_model(
            model, targets, peft.lora_rank, peft.lora_alpha, peft.lora_dropout
        )
    elif peft.method == "oft":
        peft_modules.apply_oft_to_model(model, targets, peft.oft_rank)
    else:
        peft_modules.apply_adapter_to_model(model, targets, peft.adapter_bottleneck)
    return model


def as_instructions(value, name: str = "instruction") -> list[str]:
    """``value`` (one string, or a sequence / array of strings) as a list of strings.

    Raises ``TypeError`` naming ``name`` for anything else (None, bytes, non-string items),
    which would otherwise be turned into text such as ``"None"`` or fail deep inside.
    """
    if isinstance(value, str):
        return [value]
    if (
        value is None
        or isinstance(value, (bytes, bytearray, Mapping))
        or not isinstance(value, (Sequence, np.ndarray))
    ):
        raise TypeError(f"{name} must be a string or a list of strings, got {type(value).__name__}")
    bad = [s for s in value if not isinstance(s, str)]
    if bad:
        raise TypeError(
            f"{name} must be a string or a list of strings; it holds a "
            f"{type(bad[0]).__name__}: {bad[0]!r}"
        )
    return [str(s) for s in value]


def env_obs_to_frame(obs: Mapping, device: torch.device | str = "cpu") -> dict:
    """Environment observation (single or batched) -> one policy frame.

    Returns ``rgb`` (B, 3, H, W) float in [0, 1], ``depth`` (B, 1, H, W), ``pose`` (B, 3),
    ``instruction`` list of B strings.
    """
    rgb = torch.as_tensor(np.asarray(obs["rgb"]))
    batched = rgb.dim() == 4
    if not batched:
        if rgb.dim() != 3:
            raise ValueError(
                f"obs['rgb'] must be (H, W, 3) or (B, H, W, 3); got {tuple(rgb.shape)}"
            )
        rgb = rgb[None]  # (1, H, W, 3)
    depth = torch.as_tensor(np.asarray(obs["depth"]), dtype=torch.float32)
    pose = torch.as_tensor(np.asarray(obs["pose"]), dtype=torch.float32)
    if not batched:
        depth, pose = depth[None], pose[None]  # (1, H, W, 1), (1, 3)
    instructions = as_instructions(obs["instruction"], "obs['instruction']")
    if len(instructions) != rgb.shape[0]:
        raise ValueError(f"{rgb.shape[0]} observations but {len(instructions)} instructions")
    rgb = (
        rgb.permute(0, 3, 1, 2).float() / 255.0
        if rgb.dtype == torch.uint8
        else rgb.permute(0, 3, 1, 2).float()
    )
    return {
        "rgb": rgb.to(device),  # (B, 3, H, W)
        "depth": depth.permute(0, 3, 1, 2).to(device),  # (B, 1, H, W)
        "pose": pose.to(device),  # (B, 3)
        "instruction": instructions,
    }


def make_fake_batch(
    config: ModelConfig,
    batch_size: int = 2,
    seed: int = 0,
    instructions: Sequence[str] | None = None,
) -> dict:
    """A random training batch in dataset layout (openpi's ``fake_obs`` + ``fake_act``).

    ``goal_mask`` and ``distractor_mask`` (B, T, 1, S, S) are random and never overlap.
    """
    g = torch.Generator().manual_seed(seed)
    B, T, S = batch_size, config.n_obs_steps, config.image_size
    words = ["chair", "bed", "sofa", "table", "sink", "plant"]
    batch = {
        "rgb": torch.rand(B, T, 3, S, S, generator=g),  # (B, T, 3, S, S)
        "depth": torch.rand(B, T, 1, S, S, generator=g) * 5.0,  # (B, T, 1, S, S)
        "pose": torch.randn(B, T, 3, generator=g),  # (B, T, 3)
        "action": torch.rand(B, config.horizon, config.action_dim, generator=g) * 2 - 1,
        "instruction": list(instructions)
        if instructions is not None
        else [f"find the {words[i % len(words)]}" for i in range(B)],
    }
    goal = torch.rand(B, T, 1, S, S, generator=g) > 0.8  # (B, T, 1, S, S)
    others = (torch.rand(B, T, 1, S, S, generator=g) > 0.8) & ~goal  # (B, T, 1, S, S)
    return batch | {"goal_mask": goal, "distractor_mask": others}
