"""Training inputs of the policies: fake batches (smoke tests) and PEFT layers."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from vla_gr.configs.model_schema import ModelConfig

__all__ = ["apply_peft", "make_fake_batch"]


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
