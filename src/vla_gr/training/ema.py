"""Exponential moving average of model weights (diffusion_policy's EMAModel), used for eval.

Updated by ``training/step.py``; validated with and saved by ``training/state.py``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn


def ema_decay(step: int, max_decay: float, warmup: bool = True) -> float:
    """Decay at optimiser step ``step`` (0-based): ``min(max_decay, (1 + s) / (10 + s))``
    with warmup (so early averages are not dominated by the random init), else ``max_decay``."""
    if not warmup:
        return max_decay
    return min(max_decay, (1.0 + step) / (10.0 + step))


class EMA:
    """Shadow copies of every floating-point parameter and buffer of ``model``.

    ``update`` after each optimiser step: ``shadow = d * shadow + (1 - d) * param`` for
    trainable parameters; frozen parameters and buffers are copied as they are.
    """

    def __init__(self, model: nn.Module, decay: float, warmup: bool = True) -> None:
        if not 0.0 <= decay < 1.0:
            raise ValueError(f"decay={decay} must be in [0, 1)")
        self.decay, self.warmup = decay, warmup
        self.shadow: dict[str, torch.Tensor] = {
            k: v.detach().clone() for k, v in _float_state(model).items()
        }
        self.num_updates = 0

    @torch.no_grad()
    def update(self, model: nn.Module) -> float:
        """Fold the current weights in; returns the decay used."""
        d = ema_decay(self.num_updates, self.decay, self.warmup)
        trainable = {n for n, p in model.named_parameters() if p.requires_grad}
        for name, value in _float_state(model).items():
            s = self.shadow[name]
            if name in trainable:
                s.lerp_(value.detach().to(s.dtype), 1.0 - d)
            else:
                s.copy_(value.detach())
        self.num_updates += 1
        return d

    @torch.no_grad()
    def copy_to(self, model: nn.Module) -> None:
        """Overwrite ``model``'s floating-point state with the averages."""
        state = _float_state(model)
        for name, s in self.shadow.items():
            state[name].copy_(s)

    @contextlib.contextmanager
    def average_parameters(self, model: nn.Module) -> Iterator[nn.Module]:
        """Temporarily swap the averages into ``model`` (restored on exit)."""
        backup = {k: v.detach().clone() for k, v in _float_state(model).items()}
        self.copy_to(model)
        try:
            yield model
        finally:
            state = _float_state(model)
            with torch.no_grad():
                for name, v in backup.items():
                    state[name].copy_(v)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return dict(self.shadow)

    def load_state_dict(self, shadow: dict[str, torch.Tensor], num_updates: int) -> None:
        missing = sorted(set(self.shadow) - set(shadow))
        if missing:
            raise ValueError(f"EMA state lacks {len(missing)} entries, e.g. {missing[:3]}")
        for name, s in self.shadow.items():
            if shadow[name].shape != s.shape:
                raise ValueError(
                    f"EMA entry {name!r} has shape {tuple(shadow[name].shape)}, "
                    f"model has {tuple(s.shape)}"
                )
            s.copy_(shadow[name])
        self.num_updates = int(num_updates)


def _float_state(model: nn.Module) -> dict[str, torch.Tensor]:
    """Floating-point entries of ``model.state_dict(keep_vars=True)`` (live tensors)."""
    return {
        k: (v.data if isinstance(v, nn.Parameter) else v)
        for k, v in model.state_dict(keep_vars=True).items()
        if v.is_floating_point()
    }
