"""AdamW with decoupled weight decay on >= 2-D weights only, and a warmup + cosine schedule.

Stepped by ``training/step.py``; their state is saved by ``training/state.py``.
"""

from __future__ import annotations

import math
from functools import partial

import torch
from torch import nn
from torch.optim.lr_scheduler import LambdaLR


def param_groups(model: nn.Module, weight_decay: float) -> list[dict]:
    """Trainable parameters split as nanoGPT does: decay for >= 2-D tensors (matrices,
    conv kernels, embeddings), none for biases, norm gains and 1-D / scalar parameters."""
    decay, no_decay = [], []
    for _, p in model.named_parameters():
        if p.requires_grad:
            (decay if p.dim() >= 2 else no_decay).append(p)
    if not decay and not no_decay:
        raise ValueError("the model has no trainable parameters (is everything frozen?)")
    return [
        {"params": decay, "weight_decay": weight_decay},
        {"params": no_decay, "weight_decay": 0.0},
    ]


def build_optimizer(
    model: nn.Module,
    lr: float,
    weight_decay: float,
    betas: tuple[float, float] = (0.9, 0.999),
    fused: bool | None = None,
) -> torch.optim.AdamW:
    """AdamW over :func:`param_groups`; ``fused`` defaults to True on CUDA."""
    groups = param_groups(model, weight_decay)
    if fused is None:
        fused = all(p.is_cuda for g in groups for p in g["params"])
    return torch.optim.AdamW(groups, lr=lr, betas=tuple(betas), fused=fused or None)


def warmup_cosine(step: int, warmup_steps: int, total_steps: int, min_ratio: float) -> float:
    """LR multiplier: linear 0 -> 1 over ``warmup_steps`` (step 0 gets ``1 / warmup``),
    then cosine from 1 down to ``min_ratio`` at ``total_steps`` (held there after)."""
    if warmup_steps > 0 and step < warmup_steps:
        return (step + 1) / warmup_steps
    span = max(1, total_steps - warmup_steps)
    progress = min(1.0, (step - warmup_steps) / span)
    return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


def build_scheduler(
    optimizer: torch.optim.Optimizer, warmup_steps: int, total_steps: int, min_ratio: float
) -> LambdaLR:
    """Per-step ``LambdaLR`` with :func:`warmup_cosine`."""
    fn = partial(
        warmup_cosine, warmup_steps=warmup_steps, total_steps=total_steps, min_ratio=min_ratio
    )
    return LambdaLR(optimizer, fn)


def scheduler_state(scheduler: LambdaLR) -> dict:
    """JSON-able scheduler state (the lambda is rebuilt from the config, not saved)."""
    return {
        "last_epoch": scheduler.last_epoch,
        "base_lrs": list(scheduler.base_lrs),
        "_last_lr": list(scheduler.get_last_lr()),
        "_step_count": getattr(scheduler, "_step_count", 0),
    }


def load_scheduler_state(scheduler: LambdaLR, state: dict) -> None:
    """Inverse of :func:`scheduler_state`; the LR is recomputed with the current lambda (so
    a resumed run that changed ``training.steps`` follows its new schedule)."""
    scheduler.last_epoch = int(state["last_epoch"])
    scheduler.base_lrs = list(state["base_lrs"])
    scheduler._step_count = int(state["_step_count"])
    lrs = [b * fn(scheduler.last_epoch) for b, fn in zip(scheduler.base_lrs, scheduler.lr_lambdas)]
    for group, lr in zip(scheduler.optimizer.param_groups, lrs):
        group["lr"] = lr
    scheduler._last_lr = lrs


class CPUOffloadAdamW(torch.optim.Optimizer):
    """AdamW whose fp32 master weights and moments live in CPU memory (ZeRO-Offload style).

    ``param_groups`` hold the device parameters (so ``GradScaler.unscale_``, gradient
    clipping and LR schedulers work unchanged); ``step()`` copies their gradients to the
    CPU masters, runs a CPU AdamW with the groups' current hyper-parameters, and copies
    the updated weights back. The GPU keeps only the model and its gradients.
    """

    def __init__(
        self, model: nn.Module, lr: float, weight_decay: float, betas=(0.9, 0.999)
    ) -> None:
        groups = param_groups(model, weight_decay)
        super().__init__(groups, {"lr": lr, "weight_decay": weight_decay, "betas": tuple(betas)})
        cpu_groups = []
        for g in self.param_groups:
            masters = [p.detach().to("cpu", torch.float32, copy=True) for p in g["params"]]
            cpu_groups.append({"params": masters, "weight_decay": g["weight_decay"]})
        self.inner = torch.optim.AdamW(cpu_groups, lr=lr, betas=tuple(betas))

    def _pairs(self):
        for g, cg in zip(self.param_groups, self.inner.param_groups):
            yield from zip(g["params"], cg["params"])

    @torch.no_grad()
    def step(self, closure=None):  # noqa: D102
        if closure is not None:
            raise ValueError("CPUOffloadAdamW.step does not take a closure")
        for g, cg in zip(self.param_groups, self.inner.param_groups):
            cg.update({k: g[k] for k in ("lr", "weight_decay", "betas")})
        for p, m in self._pairs():
            m.grad = None if p.grad is None else p.grad.detach().to("cpu", torch.float32)
        self.inner.step()
        for p, m in self._pairs():
            p.copy_(m.to(p.device, p.dtype))

    def state_dict(self) -> dict:
        return self.inner.state_dict()

    def load_state_dict(self, state_dict: dict) -> None:
        self.inner.load_state_dict(state_dict)
        for g, cg in zip(self.param_groups, self.inner.param_groups):
            g.update({k: cg[k] for k in ("lr", "weight_decay", "betas")})
        with torch.no_grad():
            for p, m in self._pairs():
                m.copy_(p.detach().float().cpu())
