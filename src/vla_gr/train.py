"""``vla-gr train``: train the navigation agent on expert episodes, or run a recipe's stages.

A recipe with ``pipeline.stages`` (e.g. ``--config-name recipe_vla_gr_cpu``) runs them in
order (:mod:`vla_gr.training.pipeline`: collect, train, rollouts, DAgger, S1 data, S1,
export), each resumable and skipped when its output is up to date (under torchrun the
episode stages run once, split across the ranks, and the training stages use DDP);
otherwise one training run as below.

Runs single-process or under ``torchrun --nproc_per_node=N -m vla_gr.train --config-name
config_server`` (DDP: NCCL on GPU, gloo on CPU). Read top to bottom:

1. compose + validate the config (unknown keys / bad values fail before any work); verify
   the ``training.resume`` checkpoint (a finished run stops here);
2. set up the process group and the seed (``seed + rank``); make sure the episode store
   exists and build train / held-out loaders, then create the run folder;
3. build the policy (normalisers from the data, optional init weights, PEFT), the EMA,
   AdamW + warmup-cosine, the fp16 GradScaler; restore all of it on ``training.resume``
   (``training/state.py``);
4. loop: ``train_step()`` (``training/step.py``: accumulation, AMP, clipping, EMA), then
   ``maybe_log``, ``maybe_validate`` (EMA weights: held-out loss, and closed-loop SR / SPL on
   a few ``val`` episodes when ``training.eval_episodes`` > 0, videos of the first
   ``training.eval_videos`` to TensorBoard) and ``maybe_checkpoint``
   (``latest`` / ``best`` picked by ``training.best_metric``, atomic, rank 0).

The run folder holds ``config.yaml``, ``metrics.jsonl``, ``tensorboard/`` and
``checkpoints/{step_*, latest, best}``; ``vla_gr.evaluate`` reads the checkpoints back.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from torch.nn.parallel import DistributedDataParallel

from vla_gr import checkpoint as ckpt
from vla_gr.configs.schema import VLAGRConfig
from vla_gr.policy import NavigationPolicy, VLAGRPolicy, apply_peft, make_policy
from vla_gr.training.augment import augment_batch
from vla_gr.training.closed_loop import best_score, closed_loop_metrics
from vla_gr.training.data import build_datasets, build_loaders, prepare_store
from vla_gr.training.distributed import (
    DistInfo,
    all_reduce_mean,
    process_group,
    seed_everything,
)
from vla_gr.training.ema import EMA
from vla_gr.training.logger import MetricsLogger, Progress
from vla_gr.training.optim import CPUOffloadAdamW, build_optimizer, build_scheduler
from vla_gr.training.state import Run, TrainState, check_resume_config, restore, save
from vla_gr.training.step import autocast, train_step, validate

log = logging.getLogger("vla_gr.train")


def train(cfg: VLAGRConfig, resolved: DictConfig | None = None) -> dict:
    """Train per ``cfg``; returns a summary (run folder, steps, final / best losses)."""
    resolved = resolved if resolved is not None else OmegaConf.structured(cfg)
    with process_group(cfg.training.device, cfg.training.ddp_backend) as dist:
        return _train(cfg, resolved, dist)


def _train(cfg: VLAGRConfig, resolved: DictConfig, dist: DistInfo) -> dict:
    """Resume check, set-up, restore, loop; returns the summary."""
    if not dist.is_main:  # logging on rank 0 only
        logging.getLogger("vla_gr").setLevel(logging.WARNING)
    loaded = None
    if cfg.training.resume:  # verified before any work
        loaded = ckpt.read_checkpoint(cfg.training.resume, prefer="latest")
        check_resume_config(loaded, resolved)
        if loaded.state["step"] >= cfg.training.steps:
            return _already_finished(cfg, dist, loaded)
    seed_everything(cfg.seed + dist.rank)
    run = _set_up(cfg, resolved, dist, resume_step=loaded.state["step"] if loaded else None)
    state = TrainState()
    if loaded is not None:
        state = restore(run, loaded)
        log.info("resumed from %s at step %d", loaded.path, state.step)
    try:
        _loop(run, state)
    finally:
        run.logger.close()
    return _summary(run, state)


# --------------------------------------------------------------------------- the loop


def _loop(run: Run, state: TrainState) -> None:
    """Optimiser steps until ``training.steps``: step, log, validate, checkpoint."""
    t = run.cfg.training
    progress = Progress(t.steps, state.step, enabled=run.dist.is_main and run.cfg.logging.progress)
    samples_per_step = t.batch_size * t.grad_accum * run.dist.world_size
    batches = _batches(run, state)
    try:
        while state.step < t.steps:
            micro = [
                augment_batch(next(batches), t.paraphrase_prob, t.flip_prob)
                for _ in range(t.grad_accum)
            ]
            t0 = time.perf_counter()
            state.train = train_step(
                run.train_model,
                micro,
                run.optimizer,
                scheduler=run.scheduler,
                scaler=run.scaler,
                ema=run.ema,
                ema_target=run.model,
                amp=t.amp,
                grad_clip=t.grad_clip,
                device=run.dist.device,
            )
            state.step += 1
            samples_per_s = samples_per_step / max(time.perf_counter() - t0, 1e-9)
            progress.update(state.train["loss"], state.train["lr"], samples_per_s)
            if not math.isfinite(state.train["loss"]):
                raise FloatingPointError(f"loss is {state.train['loss']} at step {state.step}")
            maybe_log(run, state, samples_per_s)
            is_best = maybe_validate(run, state)
            maybe_checkpoint(run, state, is_best)
    finally:
        progress.close()


def _batches(run: Run, state: TrainState) -> Iterator[Mapping]:
    """Training micro-batches, epoch after epoch; keeps ``state.epoch`` / ``state.position``
    at the sampler's place (a resumed run starts where the checkpoint was)."""
    run.sampler.set_position(state.epoch, state.position)
    while True:
        for batch in run.train_loader:
            state.position += run.cfg.training.batch_size
            yield batch
        state.epoch, state.position = state.epoch + 1, 0
        run.sampler.set_position(state.epoch, 0)


def _due(step: int, every: int, last: int) -> bool:
    """Whether a period of ``every`` steps (0 = only at the end) falls on ``step``."""
    return (every > 0 and step % every == 0) or step == last


def maybe_log(run: Run, state: TrainState, samples_per_s: float) -> None:
    """Every ``training.log_every`` steps: the step's loss (averaged over ranks), lr, ..."""
    t = run.cfg.training
    if not _due(state.step, t.log_every, t.steps):
        return
    loss = torch.tensor(state.train["loss"], device=run.dist.device)
    state.train["loss"] = float(all_reduce_mean(loss))
    metrics = {f"train/{k}": v for k, v in state.train.items()}
    run.logger.log(
        state.step, metrics | {"train/samples_per_s": samples_per_s, "train/epoch": state.epoch}
    )


def maybe_validate(run: Run, state: TrainState) -> bool:
    """Every ``training.val_every`` steps, with the EMA weights: held-out loss (and the goal
    head's ``val/goal_*`` metrics on the same windows) and closed-loop metrics; updates the
    best score and returns whether this step set a new best."""
    t, model, device = run.cfg.training, run.model, run.dist.device
    validates = run.val_loader is not None or t.eval_episodes > 0
    if not (validates and t.val_every and _due(state.step, t.val_every, t.steps)):
        return False
    held_out: dict[str, float] = {}
    with run.ema.average_parameters(model) if run.ema else contextlib.nullcontext():
        if run.val_loader is not None:
            state.val_loss, held_out = validate(
                model, run.val_loader, t.val_batches, device, t.amp, run.cfg.seed
            )
            state.best_val_loss = min(state.best_val_loss, state.val_loss)
        closed, clips = closed_loop_metrics(
            model, run.cfg, run.dist, lambda: autocast(device, t.amp), _rollout
        )
        state.evals = held_out | closed
    score = best_score(t.best_metric, state.val_loss, state.evals)
    is_best = score > state.score
    state.score = max(state.score, score)
    metrics = {"val/loss": state.val_loss, "val/best_loss": state.best_val_loss} | state.evals
    run.logger.log(state.step, {k: v for k, v in metrics.items() if math.isfinite(v)})
    run.logger.log_videos(state.step, clips)
    return is_best


def maybe_checkpoint(run: Run, state: TrainState, is_best: bool) -> None:
    """Every ``training.checkpoint_every`` steps, at the end and on a new best: save ``latest``
    (and ``best``; without any validation to pick it, ``best`` is ``latest``)."""
    t = run.cfg.training
    if not (_due(state.step, t.checkpoint_every, t.steps) or is_best):
        return
    picks_best = run.val_loader is not None or t.best_metric != "val_loss"
    save(run, state, ["latest"] + (["best"] if is_best or not picks_best else []))


# --------------------------------------------------------------------------- set-up


def build_policy(cfg: VLAGRConfig, normalizers: Mapping | None = None) -> NavigationPolicy:
    """The policy of ``cfg.model`` with data normalisers, init weights and PEFT applied."""
    model = make_policy(cfg.model)
    if normalizers is not None:
        model.set_normalization(normalizers)
    if cfg.training.init_from:
        loaded = ckpt.read_checkpoint(cfg.training.init_from)
        fresh = ckpt.load_model_state(
            model,
            loaded.model,
            cfg.training.init_from,
            allow_missing=cfg.training.init_allow_missing,
        )
        log.info("initialised weights from %s", cfg.training.init_from)
        if fresh:
            log.info("kept the fresh initialisation of %d entries: %s", len(fresh), fresh)
    apply_peft(model, cfg.model.peft)
    if cfg.training.gradient_checkpointing:  # the schema allows it for the dual system only
        model.use_gradient_checkpointing()
    return model


def _set_up(cfg: VLAGRConfig, resolved: DictConfig, dist: DistInfo, resume_step: int | None) -> Run:
    """Data, model, EMA, optimiser, schedule and scaler, then the run folder and its metrics
    logger (a missing dataset or a bad ``training.init_from`` leaves no run folder behind)."""
    t, device = cfg.training, dist.device
    train_set, val_set = build_datasets(cfg, prepare_store(cfg, dist))
    train_loader, sampler, val_loader = build_loaders(cfg, dist, train_set, val_set)
    model = build_policy(cfg, train_set.get_normalizers()).to(device)
    ema = EMA(model, t.ema_decay, t.ema_warmup) if t.ema_decay > 0 else None
    betas = tuple(t.betas) if t.betas else (0.9, 0.999)
    if t.optimizer_offload:
        optimizer = CPUOffloadAdamW(model, t.lr, t.weight_decay, betas)
    else:
        optimizer = build_optimizer(model, t.lr, t.weight_decay, betas)
    scheduler = build_scheduler(optimizer, t.warmup_steps, t.steps, t.min_lr_ratio)
    scaler = torch.amp.GradScaler(device.type) if t.amp == "fp16" else None
    train_model = torch.compile(model) if t.compile else model
    if dist.distributed:
        ids = [device.index] if device.type == "cuda" else None
        # the dual system's forward trains its goal head alone (S1 and S2's checks have
        # stages of their own): DDP must not wait for gradients of the parts it leaves out
        partial = isinstance(model, VLAGRPolicy)
        train_model = DistributedDataParallel(
            train_model, device_ids=ids, find_unused_parameters=partial
        )

    run_dir = _run_dir(cfg, dist)
    if dist.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(resolved))
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
    return Run(
        cfg=cfg,
        dist=dist,
        run_dir=run_dir,
        config_yaml=OmegaConf.to_yaml(resolved),
        model=model,
        train_model=train_model,
        ema=ema,
        optimizer=optimizer,
        scheduler=scheduler,
        scaler=scaler,
        train_loader=train_loader,
        sampler=sampler,
        val_loader=val_loader,
        logger=MetricsLogger(
            run_dir,
            enabled=dist.is_main,
            tensorboard=cfg.logging.tensorboard,
            wandb_cfg=cfg.logging.wandb,
            config=OmegaConf.to_container(resolved, resolve=True),
            run_name=run_dir.name,
            resume_step=resume_step,
        ),
    )


#: Panel size (pixels) and frame stride of closed-loop validation's TensorBoard videos.
VIDEO_PANEL, VIDEO_STRIDE = 128, 2


def _rollout(policy, env_kwargs: dict, indices, device, videos: int) -> tuple[dict, dict]:
    """Closed-loop validation's rollouts: the eval harness's episode loop, averaged, and
    ``val/episode_<k>`` videos of the first ``videos`` episodes (replayed, as eval's report)."""
    from vla_gr.data.collect import make_env
    from vla_gr.evaluation.runner import rollout_rows, summarize
    from vla_gr.evaluation.video import episode_clip

    rows = rollout_rows(policy, env_kwargs, indices, device)
    clips = {}
    if videos:
        env = make_env(dict(env_kwargs))
        try:
            for row in rows[:videos]:
                tag = f"val/episode_{row['episode_index']}"
                clips[tag] = episode_clip(env, row, VIDEO_PANEL, VIDEO_STRIDE)
        finally:
            env.close()
    return summarize([row["metrics"] for row in rows]), clips


def _run_dir(cfg: VLAGRConfig, dist: DistInfo) -> Path:
    """The run folder: the resumed run's, or ``output_dir/run_name`` (timestamp by default)."""
    t = cfg.training
    if t.resume:
        return Path(t.resume).absolute().parent.parent
    name = [t.run_name or time.strftime("%Y%m%d-%H%M%S")]
    if dist.distributed:  # every rank must agree on the timestamp
        torch.distributed.broadcast_object_list(name, src=0)
    return Path(t.output_dir) / name[0]


# --------------------------------------------------------------------------- summaries


def _summary(run: Run, state: TrainState) -> dict:
    """What the run reached: steps, last losses, best score, latest closed-loop metrics."""
    t = run.cfg.training
    return {
        "run_dir": str(run.run_dir),
        "steps": state.step,
        "train_loss": state.train["loss"],
        "val_loss": state.val_loss,
        "best_val_loss": state.best_val_loss,
        "best_metric": t.best_metric,
        "best_score": state.best_val_loss if t.best_metric == "val_loss" else state.score[0],
        **state.evals,
        "world_size": run.dist.world_size,
    }


def _already_finished(cfg: VLAGRConfig, dist: DistInfo, loaded: ckpt.LoadedCheckpoint) -> dict:
    """The summary of a resumed run that has nothing left to train (and a line saying so)."""
    s = loaded.state
    log.info(
        "%s is already finished at step %d (training.steps=%d): nothing to train; "
        "raise training.steps to continue it",
        loaded.path,
        s["step"],
        cfg.training.steps,
    )
    return {
        "run_dir": str(_run_dir(cfg, dist)),
        "steps": s["step"],
        "already_finished": True,
        "best_val_loss": s.get("best_val_loss"),
        "best_metric": s.get("best_metric", "val_loss"),
        "best_score": s.get("best_score"),
        "world_size": dist.world_size,
    }


# --------------------------------------------------------------------------- entry points


def run_from_cli(config_name: str, overrides: Sequence[str]) -> int:
    """``vla-gr train [--config-name NAME] [key=value ...]``; returns the exit code."""
    from vla_gr.configs import load_config

    resolved, cfg = load_config(config_name, overrides)
    logging.getLogger("vla_gr").setLevel(cfg.logging.level)
    if cfg.pipeline.stages:
        return _run_stages(cfg, resolved)
    try:
        summary = train(cfg, resolved)
    except (ckpt.CheckpointError, FileNotFoundError) as err:
        log.error("%s", err)
        return 2
    if not summary.get("already_finished"):
        log.info("done: %s", summary)
    return 0


def _run_stages(cfg: VLAGRConfig, resolved: DictConfig) -> int:
    """The recipe's stages (``pipeline.stages``), handed the training loop and the
    evaluation harness; a table of each stage's product and time. Under torchrun the process
    group is set up once for every stage (``training.device``, ``training.ddp_backend``)."""
    from vla_gr.evaluation.harness import evaluate
    from vla_gr.evaluation.merge import merge_runs
    from vla_gr.training.pipeline import run_pipeline
    from vla_gr.training.stages import Services

    services = Services(train=train, evaluate=evaluate, merge=merge_runs)
    with process_group(cfg.training.device, cfg.training.ddp_backend) as dist:
        if not dist.is_main:  # logging and the table on rank 0 only
            logging.getLogger("vla_gr").setLevel(logging.WARNING)
        try:
            records = run_pipeline(resolved, cfg, services)
        except (ckpt.CheckpointError, FileNotFoundError) as err:
            log.error("%s", err)
            return 2
    if not dist.is_main:
        return 0
    lines = ["| stage | kind | seconds | product |", "|---|---|---|---|"]
    lines += [f"| {name} | {r['kind']} | {r['seconds']:.0f} | {r['product']} |"
              for name, r in records.items()]  # fmt: skip
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    from vla_gr.configs.command import module_main

    sys.exit(module_main("train", run_from_cli))
