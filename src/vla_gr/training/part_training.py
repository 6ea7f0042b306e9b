"""One part of an agent (S1, a check of S2, the reader's tagger) trained with the training
loop's own step (:func:`~vla_gr.training.step.train_step`): on ``training.device``, in
``training.amp`` precision (fp16 with a GradScaler), clipped, and under torchrun data parallel:
each rank draws its own batches (:func:`rank_seed`), DDP averages the gradients, so every
rank holds the same weights and rank 0 writes them.

The goal head trains in the training loop itself (:mod:`vla_gr.train`); the part stages
(:mod:`.s1`, :mod:`.agent_stage`, :mod:`.instruction_reader`) use :class:`PartTrainer`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn.parallel import DistributedDataParallel

from vla_gr.training.distributed import local_device, process_rank
from vla_gr.training.step import train_step

__all__ = ["ON_CPU", "Compute", "PartTrainer", "rank_generator", "rank_seed"]


@dataclass(frozen=True)
class Compute:
    """Where and in which precision a part trains (``training.device``, ``training.amp``)."""

    device: str = "cpu"  # auto | cpu | cuda (this rank's GPU under torchrun)
    amp: str = "none"  # none | fp16 (autocast + GradScaler) | bf16 (autocast)


#: fp32 on the CPU: the part trainers' default.
ON_CPU = Compute()


class _PartLoss(nn.Module):
    """``part`` with ``loss(**batch) -> scalar`` as its forward: what DDP wraps and
    ``train_step`` calls (``{"loss": ...}``)."""

    def __init__(self, part: nn.Module, loss: Callable[..., torch.Tensor]) -> None:
        super().__init__()
        self.part, self.loss = part, loss

    def forward(self, batch: Mapping) -> dict[str, torch.Tensor]:
        return {"loss": self.loss(**batch)}


class PartTrainer:
    """Optimiser steps of ``part`` on ``loss(**batch)`` (see the module docstring).

    Moves ``part`` to this rank's device first: build its optimiser after the trainer.
    """

    def __init__(
        self,
        part: nn.Module,
        loss: Callable[..., torch.Tensor],
        compute: Compute = ON_CPU,
        grad_clip: float = 0.0,
    ) -> None:
        self.device = local_device(compute.device)
        self.amp, self.grad_clip = compute.amp, grad_clip
        self.part = part.to(self.device)
        model: nn.Module = _PartLoss(part, loss)
        if process_rank()[1] > 1:
            ids = [self.device.index] if self.device.type == "cuda" else None
            # a part may leave parameters out of a loss (S1 without S2's plan): no waiting
            model = DistributedDataParallel(model, device_ids=ids, find_unused_parameters=True)
        self.model = model
        self.scaler = torch.amp.GradScaler(self.device.type) if self.amp == "fp16" else None

    def step(self, batch: Mapping, optimizer: torch.optim.Optimizer, scheduler=None) -> float:
        """One optimiser step on this rank's ``batch`` (tensors moved to the device); returns
        this rank's loss."""
        out = train_step(
            self.model, [batch], optimizer, scheduler=scheduler, scaler=self.scaler,
            amp=self.amp, grad_clip=self.grad_clip, device=self.device,
        )  # fmt: skip
        return out["loss"]


def rank_seed(seed: int) -> int:
    """This rank's seed for its batch draws: ``seed`` on rank 0 (a single process draws as it
    did before data parallel), one derived from ``(seed, rank)`` on the others."""
    rank, _ = process_rank()
    return seed if rank == 0 else int(np.random.SeedSequence((seed, rank)).generate_state(1)[0])


def rank_generator(rng: np.random.Generator, seed: int) -> np.random.Generator:
    """The generator this rank draws its batches from: ``rng`` itself on rank 0 (where it
    also drew the held-out split), one of :func:`rank_seed` on the others."""
    return rng if process_rank()[0] == 0 else np.random.default_rng(rank_seed(seed))
