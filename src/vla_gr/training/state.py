"""The training run's state and its checkpoint: what exact resume saves and restores.

``TrainState`` is where the loop is (step, epoch, sampler position, best score, latest
metrics); ``Run`` is what the loop works with (config, model, EMA, optimiser, schedule,
scaler, loaders, logger). ``save`` writes both into a checkpoint folder through
``vla_gr.checkpoint``; ``restore`` reads one back so that a resumed run continues
bit-identically. The loop itself is ``vla_gr.train``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from omegaconf import DictConfig, OmegaConf
from torch import nn
from torch.utils.data import DataLoader

from vla_gr import __version__
from vla_gr import checkpoint as ckpt
from vla_gr.configs.schema import VLAGRConfig
from vla_gr.training.closed_loop import WORST, score_from_state, score_to_json
from vla_gr.training.distributed import DistInfo, ResumableSampler, barrier, seed_everything
from vla_gr.training.ema import EMA
from vla_gr.training.logger import MetricsLogger
from vla_gr.training.optim import load_scheduler_state, scheduler_state

if TYPE_CHECKING:
    from vla_gr.policy import NavigationPolicy

log = logging.getLogger(__name__)


@dataclass
class TrainState:
    """Where the loop is; everything here but the latest metrics is saved in a checkpoint."""

    step: int = 0  # optimiser steps done
    epoch: int = 0
    position: int = 0  # samples of this epoch this rank has consumed
    best_val_loss: float = math.inf
    score: tuple[float, float] = WORST  # best (metric, tie-break) so far, higher is better
    val_loss: float = math.nan  # latest held-out loss
    evals: dict[str, float] = field(default_factory=dict)  # latest closed-loop ``val/*``
    train: dict[str, float] = field(default_factory=lambda: {"loss": math.nan})  # latest step


@dataclass
class Run:
    """What one training run works with, built once before the loop."""

    cfg: VLAGRConfig
    dist: DistInfo
    run_dir: Path
    config_yaml: str  # the resolved config, saved in every checkpoint
    model: NavigationPolicy  # the raw module: checkpoints, EMA, validation
    train_model: nn.Module  # ``model`` compiled and/or DDP-wrapped: what ``train_step`` runs
    ema: EMA | None
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    scaler: torch.amp.GradScaler | None
    train_loader: DataLoader
    sampler: ResumableSampler
    val_loader: DataLoader | None
    logger: MetricsLogger


def check_resume_config(loaded: ckpt.LoadedCheckpoint, resolved: DictConfig) -> None:
    """Refuse a checkpoint whose model config differs from this run's."""
    old = OmegaConf.to_container(OmegaConf.create(loaded.config_yaml), resolve=True)
    new = OmegaConf.to_container(resolved, resolve=True)
    diffs = ckpt.config_differences(old.get("model", {}), new.get("model", {}), "model.")
    if diffs:
        raise ckpt.CheckpointError(
            f"checkpoint {loaded.path} was trained with another model config: {diffs[:5]}"
        )
    tdiffs = ckpt.config_differences(old.get("training", {}), new.get("training", {}), "training.")
    quiet = ("training.resume", "training.run_name", "training.output_dir")
    changed = [d for d in tdiffs if not d.startswith(quiet)]
    if changed:
        log.warning("resuming with changed training settings: %s", changed)


def save(run: Run, state: TrainState, links: list[str]) -> None:
    """Gather per-rank RNG, then rank 0 writes ``checkpoints/step_<step>`` and points
    ``links`` (``latest`` / ``best``) at it."""
    rngs = _gather_rng(run.dist)
    if run.dist.is_main:
        model, ema = run.model, run.ema
        raw = model.state_dict()
        eval_weights = {**raw, **ema.state_dict()} if ema else raw
        optim_tensors, optim_meta = ckpt.flatten_optimizer_state(run.optimizer.state_dict())
        tensors = {f"optim.{k}": v for k, v in optim_tensors.items()}
        if ema:
            tensors |= {f"raw.{k}": v for k, v in raw.items()}
        for r, (_, rng_tensors) in enumerate(rngs):
            tensors |= {f"rng.rank{r}.{k}": v for k, v in rng_tensors.items()}
        trainer_state = {
            "step": state.step,
            "epoch": state.epoch,
            "epoch_position": state.position,
            "best_val_loss": state.best_val_loss if math.isfinite(state.best_val_loss) else None,
            "best_metric": run.cfg.training.best_metric,
            "best_score": score_to_json(state.score),
            "world_size": run.dist.world_size,
            "model_weights": "ema" if ema else "raw",
            "ema_num_updates": ema.num_updates if ema else 0,
            "optimizer": optim_meta,
            "scheduler": scheduler_state(run.scheduler),
            "scaler": run.scaler.state_dict() if run.scaler is not None else None,
            "rng": [j for j, _ in rngs],
            "vla_gr_version": __version__,
            "torch_version": torch.__version__,
        }
        root = run.run_dir / "checkpoints"
        ckpt.save_checkpoint(
            root, state.step, eval_weights, trainer_state, run.config_yaml, tensors, links
        )
        ckpt.prune_checkpoints(root, run.cfg.training.keep_checkpoints)
    barrier()


def restore(run: Run, loaded: ckpt.LoadedCheckpoint) -> TrainState:
    """Load weights, EMA, optimiser, schedule, scaler and RNG from ``loaded`` into ``run``;
    returns the state to continue from exactly."""
    s, dist = loaded.state, run.dist
    raw = loaded.group("raw") if s["model_weights"] == "ema" else loaded.model
    ckpt.load_model_state(run.model, raw, str(loaded.path))
    if run.ema is not None:
        if s["model_weights"] != "ema":
            raise ckpt.CheckpointError(f"checkpoint {loaded.path} has no EMA weights (ema_decay=0)")
        run.ema.load_state_dict(loaded.model, s["ema_num_updates"])
    optim = ckpt.unflatten_optimizer_state(loaded.group("optim"), s["optimizer"])
    try:
        run.optimizer.load_state_dict(optim)
    except (ValueError, KeyError) as err:
        raise ckpt.CheckpointError(
            f"checkpoint {loaded.path}: optimizer state does not fit ({err})"
        ) from None
    load_scheduler_state(run.scheduler, s["scheduler"])
    if run.scaler is not None and s.get("scaler"):
        run.scaler.load_state_dict(s["scaler"])
    same_world = s["world_size"] == dist.world_size
    if same_world:
        ckpt.restore_rng(s["rng"][dist.rank], loaded.group(f"rng.rank{dist.rank}"))
    else:
        log.warning(
            "checkpoint has %d ranks, this run %d: RNG reseeded, data order shifts",
            s["world_size"],
            dist.world_size,
        )
        seed_everything(run.cfg.seed + dist.rank + 7919 * s["step"])
    return TrainState(
        step=s["step"],
        epoch=s["epoch"],
        position=s["epoch_position"] if same_world else 0,
        best_val_loss=s["best_val_loss"] if s["best_val_loss"] is not None else math.inf,
        score=score_from_state(s, run.cfg.training.best_metric),
    )


def _gather_rng(dist: DistInfo) -> list:
    """Every rank's (JSON RNG part, RNG tensors), gathered on all ranks."""
    mine = ckpt.capture_rng()
    if not dist.distributed:
        return [mine]
    out: list = [None] * dist.world_size
    torch.distributed.all_gather_object(out, mine)
    return out
