"""Adapt the goal head of a trained agent to a shifted world (a recipe's ``adapt`` stage).

The world changed in a way the goal head never saw (a held-out house style: other walls,
floors, light and materials, :mod:`vla_gr.envs.house_style`); frames collected there (expert
episodes, relabelled DAgger rollouts of the agent itself) teach the head the new look.
``training.adapt.method``:

- ``lora`` / ``oft``: peft layers on ``targets`` of the goal head
  (:mod:`vla_gr.core.peft_modules`), every other weight frozen; after training they are merged
  into the base weights, checked to give the unmerged model's outputs on held-out stored
  frames, and the agent is written without adapters: the same checkpoint format and keys, no
  inference overhead;
- ``full``: every goal-head weight trains (the comparison).

Everything else (S1, S2's checks, the reader, every inference setting) is the input
checkpoint's, tensor for tensor. The summary (trainable share, seconds, the held-out goal loss
and IoU before and after, the merge check) is logged and written into the agent's training
state as ``goal_head_adaptation``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, RandomSampler, Subset

from vla_gr.training.part_training import ON_CPU, Compute

log = logging.getLogger(__name__)

__all__ = ["MERGE_ATOL", "adapt_goal_head", "add_adapters", "frame_windows", "merged_difference"]

#: Largest |merged - unmerged| goal-head logit accepted (float32 rounding of W + B A).
MERGE_ATOL = 1e-4
#: Held-out windows the head is measured on before and after (a fixed draw).
VAL_WINDOWS = 512


def add_adapters(policy: nn.Module, adapt) -> dict[str, float]:
    """Make ``policy``'s goal head trainable as ``adapt`` (``training.adapt``) says, everything
    else frozen; returns the parameter counts and the trainable share."""
    from vla_gr.core.peft_modules import apply_lora_to_model, apply_oft_to_model

    head = policy.goal_head
    base = sum(p.numel() for p in head.parameters())
    total = sum(p.numel() for p in policy.parameters())
    policy.requires_grad_(False)
    if adapt.method == "full":
        head.requires_grad_(True)
    elif adapt.method == "lora":
        apply_lora_to_model(head, list(adapt.targets), adapt.rank, adapt.alpha)
    else:
        apply_oft_to_model(head, list(adapt.targets), rank=adapt.rank)
    trainable = sum(p.numel() for p in policy.parameters() if p.requires_grad)
    return {
        "trainable_parameters": trainable,
        "goal_head_parameters": base,
        "agent_parameters": total,
        "share_of_goal_head": trainable / base,
        "share_of_agent": trainable / total,
    }


@torch.no_grad()
def merged_difference(policy: nn.Module, batch: dict) -> float:
    """Merge the goal head's adapters into its weights (in place) and return the largest
    |merged - unmerged| logit on ``batch``'s frames; RuntimeError above :data:`MERGE_ATOL`."""
    from vla_gr.core.peft_modules import merge_peft

    policy.eval()
    before = policy.goal_outputs(batch)
    merge_peft(policy.goal_head, bottleneck="raise")
    after = policy.goal_outputs(batch)
    keys = [k for k in ("pixel_logits", "visible_logits", "category_logits") if k in before]
    diff = max(float((after[k] - before[k]).abs().max()) for k in keys)
    if not diff <= MERGE_ATOL:
        raise RuntimeError(f"merged goal head differs from the unmerged one by {diff:.2e}")
    return diff


def frame_windows(store: Path, split: str, adapt, seed: int):
    """The store's last-frame windows of ``split`` (episodes held out by ``val_ratio``),
    RGB as uint8 and depth as float16 in memory (half the bytes; 2.4 mm at 5 m)."""
    from vla_gr.data.dataset import EpisodeWindowDataset

    return EpisodeWindowDataset(
        store, n_obs_steps=1, horizon=1, split=split, val_ratio=adapt.val_ratio, seed=seed,
        rgb_uint8=True, depth_float16=True,
    )  # fmt: skip


def adapt_goal_head(
    init: str | Path,
    store: str | Path,
    out: str | Path,
    adapt,
    seed: int = 0,
    compute: Compute = ON_CPU,
) -> dict:
    """Adapt the goal head of checkpoint ``init`` on the frames of ``store`` as ``adapt``
    (``training.adapt``) says and write the whole agent to ``out``; returns the summary."""
    from vla_gr.training.agent_stage import build_agent_from, write_agent
    from vla_gr.training.augment import augment_batch
    from vla_gr.training.data import make_loader
    from vla_gr.training.distributed import local_device
    from vla_gr.training.optim import build_optimizer, build_scheduler
    from vla_gr.training.step import to_device, train_step, validate

    t0 = time.perf_counter()
    torch.manual_seed(seed)
    policy, loaded, config = build_agent_from(init, "goal_head", [], keep_part=True, forced=[])
    counts = add_adapters(policy, adapt)
    log.info("adapt (%s): %d of %d goal-head parameters train (%.2f%%)", adapt.method,
             counts["trainable_parameters"], counts["goal_head_parameters"],
             100 * counts["share_of_goal_head"])  # fmt: skip
    train_set, val_set = (frame_windows(Path(store), s, adapt, seed) for s in ("train", "val"))
    picked = np.random.default_rng(seed).permutation(len(val_set))[:VAL_WINDOWS]
    val_loader = DataLoader(Subset(val_set, np.sort(picked).tolist()), batch_size=adapt.batch_size)
    draws = RandomSampler(
        train_set, replacement=True, num_samples=adapt.steps * adapt.batch_size,
        generator=torch.Generator().manual_seed(seed),
    )  # fmt: skip
    loader = make_loader(train_set, adapt.batch_size, draws, 0, seed, pin=False)
    device = local_device(compute.device)
    policy.to(device)
    measure = len(val_loader)

    def held_out() -> dict[str, float]:
        loss, metrics = validate(policy, val_loader, measure, device, compute.amp, seed)
        return {"loss": round(loss, 4), "goal_iou": round(metrics["val/goal_iou"], 4)}

    before = held_out()
    optimizer = build_optimizer(policy, adapt.lr, adapt.weight_decay)
    scheduler = build_scheduler(optimizer, adapt.warmup_steps, adapt.steps, 0.05)
    scaler = torch.amp.GradScaler(device.type) if compute.amp == "fp16" else None
    t_train = time.perf_counter()
    for step, batch in enumerate(loader, start=1):
        batch = augment_batch(batch, adapt.paraphrase_prob, adapt.flip_prob)
        out_step = train_step(
            policy, [batch], optimizer, scheduler=scheduler, scaler=scaler, amp=compute.amp,
            grad_clip=1.0, device=device,
        )  # fmt: skip
        if step % 50 == 0 or step == adapt.steps:
            log.info("adapt step %d/%d: loss %.4f", step, adapt.steps, out_step["loss"])
    train_seconds = time.perf_counter() - t_train
    after = held_out()
    merge_diff = None
    if adapt.method != "full":
        merge_diff = merged_difference(policy, to_device(next(iter(val_loader)), device))
    summary = {
        "method": adapt.method,
        "targets": list(adapt.targets) if adapt.method != "full" else ["goal_head"],
        "rank": adapt.rank if adapt.method != "full" else None,
        "steps": adapt.steps,
        "batch_size": adapt.batch_size,
        "lr": adapt.lr,
        "store": str(store),
        "train_windows": len(train_set),
        **counts,
        "held_out_before": before,
        "held_out_after": after,
        "merge_max_abs_diff": merge_diff,
        "train_seconds": round(train_seconds, 1),
        "seconds": round(time.perf_counter() - t0, 1),  # loading, measuring, training, merging
    }
    policy.cpu().eval()
    write_agent(policy, loaded, config, out, {"goal_head_adaptation": summary})
    log.info("adapted goal head written to %s: %s", out, summary)
    return summary
