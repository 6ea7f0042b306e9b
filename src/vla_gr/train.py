"""``vla-gr train``: train the navigation agent on expert episodes.

Runs single-process or under ``torchrun --nproc_per_node=N -m vla_gr.train --config-name
config_server`` (DDP: NCCL on GPU, gloo on CPU). Read top to bottom:

1. compose + validate the config (unknown keys / bad values fail before any work);
2. set up the process group, the run folder and the seed (``seed + rank``);
3. make sure the episode store exists, build train / held-out loaders;
4. build the policy (normalisers from the data, optional init weights, PEFT), the EMA,
   AdamW + warmup-cosine, the fp16 GradScaler; restore all of it on ``training.resume``;
5. loop: ``train_step()`` (accumulation, AMP, clipping, EMA), log, validate (EMA weights:
   held-out loss, and closed-loop SR / SPL on a few ``val`` episodes when
   ``training.eval_episodes`` > 0), checkpoint ``latest`` / ``best`` (picked by
   ``training.best_metric``) atomically on rank 0.

The run folder holds ``config.yaml``, ``metrics.jsonl``, ``tensorboard/`` and
``checkpoints/{step_*, latest, best}``.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from torch import nn
from torch.nn.parallel import DistributedDataParallel

from vla_gr import __version__
from vla_gr.configs.schema import VLAGRConfig
from vla_gr.policy import VLAGRPolicy, apply_peft
from vla_gr.training import checkpoint as ckpt
from vla_gr.training.closed_loop import (
    WORST,
    best_score,
    closed_loop_metrics,
    score_from_state,
    score_to_json,
)
from vla_gr.training.data import build_datasets, build_loaders, prepare_store
from vla_gr.training.distributed import (
    DistInfo,
    all_reduce_mean,
    barrier,
    cleanup_distributed,
    seed_everything,
    setup_distributed,
)
from vla_gr.training.ema import EMA
from vla_gr.training.logger import MetricsLogger, Progress
from vla_gr.training.optim import (
    CPUOffloadAdamW,
    build_optimizer,
    build_scheduler,
    load_scheduler_state,
    scheduler_state,
)

log = logging.getLogger("vla_gr.train")

AMP_DTYPES = {"none": None, "fp16": torch.float16, "bf16": torch.bfloat16}


# --------------------------------------------------------------------------- one step


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
    Returns ``loss`` (mean over micro-batches), ``grad_norm`` (before clipping), ``lr``.
    """
    device = torch.device(device)
    model.train()
    n = len(micro_batches)
    lr = optimizer.param_groups[0]["lr"]
    total = torch.zeros((), device=device)
    for i, batch in enumerate(micro_batches):
        last = i == n - 1
        is_ddp = isinstance(model, DistributedDataParallel)
        with model.no_sync() if is_ddp and not last else contextlib.nullcontext():
            with autocast(device, amp):
                loss = model(to_device(batch, device))["loss"] / n
            (scaler.scale(loss) if scaler is not None else loss).backward()
        total += loss.detach().float()
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
    return {"loss": float(total), "grad_norm": float(grad_norm), "lr": float(lr)}


@torch.no_grad()
def validation_loss(
    model: nn.Module, loader, max_batches: int, device: torch.device, amp: str, seed: int
) -> float:
    """Mean loss over up to ``max_batches`` held-out batches per rank (all ranks averaged).

    The noise of the flow / diffusion loss is drawn from a fixed seed inside a forked RNG,
    so successive validations are comparable and training randomness is untouched.
    """
    was_training = model.training
    model.eval()
    total = torch.zeros(2, device=device)  # (sum of losses * B, number of samples)
    devices = [device] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(seed)
        for i, batch in enumerate(loader):
            if i >= max_batches:
                break
            with autocast(device, amp):
                loss = model(to_device(batch, device))["loss"].float()
            B = batch["action"].shape[0]
            total += torch.stack([loss * B, torch.tensor(float(B), device=device)])
    model.train(was_training)
    total = all_reduce_mean(total)
    return float(total[0] / total[1].clamp(min=1.0))


# --------------------------------------------------------------------------- set-up


def build_policy(cfg: VLAGRConfig, normalizers: Mapping | None = None) -> VLAGRPolicy:
    """The policy of ``cfg.model`` with data normalisers, init weights and PEFT applied."""
    model = VLAGRPolicy(cfg.model)
    if normalizers is not None:
        model.set_normalization(normalizers)
    if cfg.training.init_from:
        loaded = ckpt.read_checkpoint(cfg.training.init_from)
        ckpt.load_model_state(model, loaded.model, cfg.training.init_from)
        log.info("initialised weights from %s", cfg.training.init_from)
    apply_peft(model, cfg.model.peft)
    return model


def _run_dir(cfg: VLAGRConfig, dist: DistInfo) -> Path:
    """The run folder: the resumed run's, or ``output_dir/run_name`` (timestamp by default)."""
    t = cfg.training
    if t.resume:
        return Path(t.resume).absolute().parent.parent
    name = [t.run_name or time.strftime("%Y%m%d-%H%M%S")]
    if dist.distributed:  # every rank must agree on the timestamp
        torch.distributed.broadcast_object_list(name, src=0)
    return Path(t.output_dir) / name[0]


def _check_resume_config(loaded: ckpt.LoadedCheckpoint, resolved: DictConfig) -> None:
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


def _gather_rng(dist: DistInfo) -> list:
    """Every rank's (JSON RNG part, RNG tensors), gathered on all ranks."""
    mine = ckpt.capture_rng()
    if not dist.distributed:
        return [mine]
    out: list = [None] * dist.world_size
    torch.distributed.all_gather_object(out, mine)
    return out


# --------------------------------------------------------------------------- the run


def train(cfg: VLAGRConfig, resolved: DictConfig | None = None) -> dict:
    """Train per ``cfg``; returns a summary (run folder, steps, final / best losses)."""
    resolved = resolved if resolved is not None else OmegaConf.structured(cfg)
    dist = setup_distributed(cfg.training.device, cfg.training.ddp_backend)
    try:
        return _train(cfg, resolved, dist)
    finally:
        cleanup_distributed()


def _train(cfg: VLAGRConfig, resolved: DictConfig, dist: DistInfo) -> dict:
    t, device = cfg.training, dist.device
    if not dist.is_main:  # logging on rank 0 only
        logging.getLogger("vla_gr").setLevel(logging.WARNING)
    loaded = ckpt.read_checkpoint(t.resume) if t.resume else None  # verified before any work
    if loaded is not None:
        _check_resume_config(loaded, resolved)
    run_dir = _run_dir(cfg, dist)
    seed_everything(cfg.seed + dist.rank)
    if dist.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(resolved))
    config_yaml = OmegaConf.to_yaml(resolved)

    # Data.
    store_path = prepare_store(cfg, dist)
    train_set, val_set = build_datasets(cfg, store_path)
    train_loader, sampler, val_loader = build_loaders(cfg, dist, train_set, val_set)

    # Model, EMA, optimiser, schedule, scaler.
    model = build_policy(cfg, train_set.get_normalizers()).to(device)
    ema = EMA(model, t.ema_decay, t.ema_warmup) if t.ema_decay > 0 else None
    betas = tuple(t.betas) if t.betas else (0.9, 0.999)
    if t.optimizer_offload:
        optimizer = CPUOffloadAdamW(model, t.lr, t.weight_decay, betas)
    else:
        optimizer = build_optimizer(model, t.lr, t.weight_decay, betas)
    scheduler = build_scheduler(optimizer, t.warmup_steps, t.steps, t.min_lr_ratio)
    scaler = torch.amp.GradScaler(device.type) if t.amp == "fp16" else None

    step, epoch, position, best, score = 0, 0, 0, math.inf, WORST
    if loaded is not None:
        step, epoch, position, best = _restore(
            loaded, model, ema, optimizer, scheduler, scaler, dist, cfg.seed
        )
        score = score_from_state(loaded.state, t.best_metric)
        log.info("resumed from %s at step %d", loaded.path, step)
    sampler.set_position(epoch, position)

    train_model: nn.Module = model
    if t.compile:
        train_model = torch.compile(model)
    if dist.distributed:
        ids = [device.index] if device.type == "cuda" else None
        train_model = DistributedDataParallel(train_model, device_ids=ids)

    logger = MetricsLogger(
        run_dir,
        enabled=dist.is_main,
        tensorboard=cfg.logging.tensorboard,
        wandb_cfg=cfg.logging.wandb,
        config=OmegaConf.to_container(resolved, resolve=True),
        run_name=run_dir.name,
    )
    progress = Progress(t.steps, step, enabled=dist.is_main and cfg.logging.progress)
    n_params = sum(p.numel() for p in model.parameters())
    n_train = sum(p.numel() for p in model.parameters() if p.requires_grad)
    log.info(
        "run %s: %d windows (%d held out), %s parameters (%s trainable), device %s",
        run_dir,
        len(train_set),
        len(val_set) if val_set else 0,
        f"{n_params:,}",
        f"{n_train:,}",
        device,
    )
    samples_per_step = t.batch_size * t.grad_accum * dist.world_size
    batches = iter(train_loader)
    val_loss, evals = math.nan, {}
    validates = val_loader is not None or t.eval_episodes > 0
    picks_best = val_loader is not None or t.best_metric != "val_loss"  # else: best = latest
    last = {"loss": math.nan}
    try:
        while step < t.steps:
            micro = []
            for _ in range(t.grad_accum):
                try:
                    micro.append(next(batches))
                except StopIteration:
                    epoch, position = epoch + 1, 0
                    sampler.set_position(epoch, 0)
                    batches = iter(train_loader)
                    micro.append(next(batches))
                position += t.batch_size
            t0 = time.perf_counter()
            last = train_step(
                train_model,
                micro,
                optimizer,
                scheduler=scheduler,
                scaler=scaler,
                ema=ema,
                ema_target=model,
                amp=t.amp,
                grad_clip=t.grad_clip,
                device=device,
            )
            step += 1
            sps = samples_per_step / max(time.perf_counter() - t0, 1e-9)
            progress.update(last["loss"], last["lr"], sps)
            if not math.isfinite(last["loss"]):
                raise FloatingPointError(f"loss is {last['loss']} at step {step}")
            if step % t.log_every == 0 or step == t.steps:
                last["loss"] = float(all_reduce_mean(torch.tensor(last["loss"], device=device)))
                logger.log(
                    step,
                    {f"train/{k}": v for k, v in last.items()}
                    | {"train/samples_per_s": sps, "train/epoch": epoch},
                )
            is_best = False
            if validates and t.val_every and (step % t.val_every == 0 or step == t.steps):
                with ema.average_parameters(model) if ema else contextlib.nullcontext():
                    if val_loader is not None:
                        val_loss = validation_loss(
                            model, val_loader, t.val_batches, device, t.amp, cfg.seed
                        )
                        best = min(best, val_loss)
                    evals = closed_loop_metrics(model, cfg, dist, lambda: autocast(device, t.amp))
                new_score = best_score(t.best_metric, val_loss, evals)
                is_best = new_score > score
                score = max(score, new_score)
                metrics = {"val/loss": val_loss, "val/best_loss": best} | evals
                logger.log(step, {k: v for k, v in metrics.items() if math.isfinite(v)})
            periodic = t.checkpoint_every and step % t.checkpoint_every == 0
            if periodic or step == t.steps or is_best:
                links = ["latest"] + (["best"] if is_best or not picks_best else [])
                _save(
                    run_dir,
                    step,
                    epoch,
                    position,
                    (best, t.best_metric, score),
                    model,
                    ema,
                    optimizer,
                    scheduler,
                    scaler,
                    dist,
                    config_yaml,
                    links,
                    t.keep_checkpoints,
                )
    finally:
        progress.close()
        logger.close()
    return {
        "run_dir": str(run_dir),
        "steps": step,
        "train_loss": last["loss"],
        "val_loss": val_loss,
        "best_val_loss": best,
        "best_metric": t.best_metric,
        "best_score": best if t.best_metric == "val_loss" else score[0],
        **evals,
        "world_size": dist.world_size,
    }


# --------------------------------------------------------------------------- checkpoints


def _save(
    run_dir,
    step,
    epoch,
    position,
    best,
    model,
    ema,
    optimizer,
    scheduler,
    scaler,
    dist,
    config_yaml,
    links,
    keep,
) -> None:
    """Gather per-rank RNG, then rank 0 writes ``checkpoints/step_<step>``.

    ``best`` is (lowest val loss, best_metric name, best score of :func:`best_score`).
    """
    best, best_metric, score = best
    rngs = _gather_rng(dist)
    if dist.is_main:
        raw = model.state_dict()
        eval_weights = {**raw, **ema.state_dict()} if ema else raw
        optim_tensors, optim_meta = ckpt.flatten_optimizer_state(optimizer.state_dict())
        tensors = {f"optim.{k}": v for k, v in optim_tensors.items()}
        if ema:
            tensors |= {f"raw.{k}": v for k, v in raw.items()}
        for r, (_, rng_tensors) in enumerate(rngs):
            tensors |= {f"rng.rank{r}.{k}": v for k, v in rng_tensors.items()}
        state = {
            "step": step,
            "epoch": epoch,
            "epoch_position": position,
            "best_val_loss": best if math.isfinite(best) else None,
            "best_metric": best_metric,
            "best_score": score_to_json(score),
            "world_size": dist.world_size,
            "model_weights": "ema" if ema else "raw",
            "ema_num_updates": ema.num_updates if ema else 0,
            "optimizer": optim_meta,
            "scheduler": scheduler_state(scheduler),
            "scaler": scaler.state_dict() if scaler is not None else None,
            "rng": [j for j, _ in rngs],
            "vla_gr_version": __version__,
            "torch_version": torch.__version__,
        }
        root = run_dir / "checkpoints"
        ckpt.save_checkpoint(root, step, eval_weights, state, config_yaml, tensors, links)
        ckpt.prune_checkpoints(root, keep)
    barrier()


def _restore(loaded, model, ema, optimizer, scheduler, scaler, dist, seed):
    """Load everything needed to continue exactly; returns (step, epoch, position, best)."""
    s = loaded.state
    raw = loaded.group("raw") if s["model_weights"] == "ema" else loaded.model
    ckpt.load_model_state(model, raw, str(loaded.path))
    if ema is not None:
        if s["model_weights"] != "ema":
            raise ckpt.CheckpointError(f"checkpoint {loaded.path} has no EMA weights (ema_decay=0)")
        ema.load_state_dict(loaded.model, s["ema_num_updates"])
    optim = ckpt.unflatten_optimizer_state(loaded.group("optim"), s["optimizer"])
    try:
        optimizer.load_state_dict(optim)
    except (ValueError, KeyError) as err:
        raise ckpt.CheckpointError(
            f"checkpoint {loaded.path}: optimizer state does not fit ({err})"
        ) from None
    load_scheduler_state(scheduler, s["scheduler"])
    if scaler is not None and s.get("scaler"):
        scaler.load_state_dict(s["scaler"])
    if s["world_size"] == dist.world_size:
        ckpt.restore_rng(s["rng"][dist.rank], loaded.group(f"rng.rank{dist.rank}"))
    else:
        log.warning(
            "checkpoint has %d ranks, this run %d: RNG reseeded, data order shifts",
            s["world_size"],
            dist.world_size,
        )
        seed_everything(seed + dist.rank + 7919 * s["step"])
    best = s["best_val_loss"] if s["best_val_loss"] is not None else math.inf
    position = s["epoch_position"] if s["world_size"] == dist.world_size else 0
    return s["step"], s["epoch"], position, best


# --------------------------------------------------------------------------- entry points


def run_from_cli(config_name: str, overrides: Sequence[str]) -> int:
    """``vla-gr train [--config-name NAME] [key=value ...]``; returns the exit code."""
    from vla_gr.configs import load_config

    resolved, cfg = load_config(config_name, overrides)
    logging.getLogger("vla_gr").setLevel(cfg.logging.level)
    try:
        summary = train(cfg, resolved)
    except (ckpt.CheckpointError, FileNotFoundError) as err:
        log.error("%s", err)
        return 2
    log.info("done: %s", summary)
    return 0


if __name__ == "__main__":
    from vla_gr.configs.command import module_main

    sys.exit(module_main("train", run_from_cli))
