"""One optimiser step and the held-out loss: what ``vla_gr.train``'s loop runs each step.

``train_step`` accumulates micro-batches (AMP, GradScaler, clipping, EMA, DDP ``no_sync``);
``validate`` averages the held-out loss with fixed noise (and measures the goal head). The
loop around them is ``vla_gr.train``; what it saves between steps is ``training/state.py``.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping, Sequence

import torch
from torch import nn
from torch.nn.parallel import DistributedDataParallel

from vla_gr.agent.perception import confusion_metrics
from vla_gr.training.distributed import all_reduce_mean
from vla_gr.training.ema import EMA

AMP_DTYPES = {"none": None, "fp16": torch.float16, "bf16": torch.bfloat16}


def autocast(device: torch.device, amp: str):
    """Autocast context for ``amp`` in {none, fp16, bf16} on ``device``."""
    dtype = AMP_DTYPES[amp]
    if dtype is None:
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=dtype)


def to_device(batch: Mapping, device: torch.device) -> dict:
    """Move the tensors of a batch to ``device`` (strings stay as they are)."""
    return {
        k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v
        for k, v in batch.items()
    }


def train_step(
    model: nn.Module,
    micro_batches: Sequence[Mapping],
    optimizer: torch.optim.Optimizer,
    *,
    scheduler=None,
    scaler: torch.amp.GradScaler | None = None,
    ema: EMA | None = None,
    ema_target: nn.Module | None = None,
    amp: str = "none",
    grad_clip: float = 0.0,
    device: torch.device | str = "cpu",
) -> dict[str, float]:
    """One optimiser step over ``len(micro_batches)`` accumulated micro-batches.

    Each micro-batch loss is divided by the number of micro-batches, so K equal
    micro-batches of size b give the gradient of one batch of K * b. Under DDP the
    gradient all-reduce runs only on the last micro-batch (``no_sync`` before).
    Returns ``loss`` (mean over micro-batches), ``grad_norm`` (before clipping), ``lr``, and
    the mean of every other scalar the model returns (e.g. the goal head's loss parts).
    """
    device = torch.device(device)
    model.train()
    n = len(micro_batches)
    lr = optimizer.param_groups[0]["lr"]
    total = torch.zeros((), device=device)
    parts: dict[str, torch.Tensor] = {}
    for i, batch in enumerate(micro_batches):
        last = i == n - 1
        is_ddp = isinstance(model, DistributedDataParallel)
        with model.no_sync() if is_ddp and not last else contextlib.nullcontext():
            with autocast(device, amp):
                out = model(to_device(batch, device))
                loss = out["loss"] / n
            (scaler.scale(loss) if scaler is not None else loss).backward()
        total += loss.detach().float()
        for key, value in out.items():
            if key != "loss" and isinstance(value, torch.Tensor) and value.numel() == 1:
                parts[key] = parts.get(key, 0.0) + value.detach().float() / n
    if scaler is not None:
        scaler.unscale_(optimizer)
    params = [p for g in optimizer.param_groups for p in g["params"]]
    max_norm = grad_clip if grad_clip > 0 else math.inf
    grad_norm = torch.nn.utils.clip_grad_norm_(params, max_norm)
    if scaler is not None:
        scaler.step(optimizer)  # skipped when the fp16 gradients overflowed
        scaler.update()
    else:
        optimizer.step()
    optimizer.zero_grad(set_to_none=True)
    if scheduler is not None:
        scheduler.step()
    if ema is not None:
        ema.update(ema_target if ema_target is not None else model)
    scalars = {k: float(v) for k, v in parts.items()}
    return scalars | {"loss": float(total), "grad_norm": float(grad_norm), "lr": float(lr)}


#: Logged name of each goal-head metric of ``confusion_metrics``.
GOAL_METRICS = {
    "pixel_precision": "val/goal_precision",
    "pixel_recall": "val/goal_recall",
    "pixel_iou": "val/goal_iou",
    "visible_accuracy": "val/goal_visible_accuracy",
    "on_distractor": "val/goal_on_distractor",
}


@torch.no_grad()
def validation_loss(
    model: nn.Module, loader, max_batches: int, device: torch.device, amp: str, seed: int
) -> float:
    """Mean loss over up to ``max_batches`` held-out batches per rank (see ``validate``)."""
    return validate(model, loader, max_batches, device, amp, seed)[0]


@torch.no_grad()
def validate(
    model: nn.Module, loader, max_batches: int, device: torch.device, amp: str, seed: int
) -> tuple[float, dict[str, float]]:
    """Mean loss over up to ``max_batches`` held-out batches per rank (all ranks averaged)
    and the ``GOAL_METRICS`` of the confusion counts its ``validation_step`` returns ({}
    when it returns none: the end-to-end policy).

    The noise of the flow / diffusion loss is drawn from a fixed seed inside a forked RNG,
    so successive validations are comparable and training randomness is untouched.
    """
    was_training = model.training
    model.eval()
    total = torch.zeros(2, device=device)  # (sum of losses * B, number of samples)
    counts: dict[str, int] = {}
    devices = [device] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(seed)
        for i, batch in enumerate(loader):
            if i >= max_batches:
                break
            batch = to_device(batch, device)
            with autocast(device, amp):
                loss, batch_counts = model.validation_step(batch)
                for key, n in batch_counts.items():
                    counts[key] = counts.get(key, 0) + n
            B = batch["rgb"].shape[0]
            total += torch.stack([loss * B, torch.tensor(float(B), device=device)])
    model.train(was_training)
    total = all_reduce_mean(total)
    metrics: dict[str, float] = {}
    if counts:  # ratios of rank means are ratios of sums
        keys = sorted(counts)
        summed = all_reduce_mean(torch.tensor([float(counts[k]) for k in keys], device=device))
        values = confusion_metrics(dict(zip(keys, summed.tolist())))
        metrics = {name: values[key] for key, name in GOAL_METRICS.items()}
    return float(total[0] / total[1].clamp(min=1.0)), metrics
