"""Train the learned S1 of a dual-system agent on relabelled rollouts (:mod:`.s1_data`).

The agent's S2 (goal head) comes from ``init`` and stays fixed; S1 (``model.s1``) is trained
by imitation of the local teacher: the configured head's loss on the teacher's (v, w) chunk
of ``model.s1.head.horizon`` steps (the labels of the next steps along the same episode, the
last one repeated at its end) plus BCE on the teacher's STOP. Whole episodes are held out
for validation; the S1 weights with the lowest validation loss are written, with
``model.s1.kind=learned``, as a checkpoint that ``vla-gr eval`` loads like any other.
With ``settings=["s1.use_s2=false"]`` (the "without S2" ablation) S1 trains on the empty plan
vectors it reads at inference.

A recipe's ``s1`` stage runs it (``training.s1.*``) on the ``s1_data`` stages' folders.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from vla_gr.agent.followers.s1_inputs import PlanMemory
from vla_gr.errors import UserError
from vla_gr.training.agent_stage import build_agent_from, write_agent
from vla_gr.training.optim import build_optimizer, build_scheduler
from vla_gr.training.part_training import ON_CPU, Compute, PartTrainer, rank_generator
from vla_gr.training.s1_data import load_s1_data
from vla_gr.training.step import to_device

log = logging.getLogger(__name__)

__all__ = ["S1Batches", "plans_without_s2", "train_s1"]


class S1Batches:
    """Random batches of S1 samples with teacher chunks assembled within episodes.

    Args:
        data: the arrays of :func:`~vla_gr.training.s1_data.load_s1_data`, ordered by episode
            (each episode's frames contiguous, in time order).
        horizon: chunk length H.
        indices: the frames to draw from (a train or validation split).
    """

    def __init__(self, data: dict[str, np.ndarray], horizon: int, indices: np.ndarray) -> None:
        self.data, self.horizon, self.indices = data, int(horizon), np.asarray(indices)
        episode = data["episode"]
        starts = np.r_[True, episode[1:] != episode[:-1]]  # (N,)
        ends = np.r_[starts[1:], True]  # (N,) last frame of its episode
        last = np.flatnonzero(ends)  # (E,)
        self.episode_last = last[np.cumsum(starts) - 1]  # (N,) index of the episode's last frame

    def batch(self, rows: np.ndarray) -> dict[str, torch.Tensor]:
        """Tensors for frame indices ``rows`` (B,): rgb, depth, plan, chunk (B, H, 2), stop."""
        steps = rows[:, None] + np.arange(self.horizon)[None]  # (B, H)
        steps = np.minimum(steps, self.episode_last[rows][:, None])  # (B, H) clipped to episode
        d = self.data
        return {
            "rgb": torch.from_numpy(d["rgb"][rows]),  # (B, 3, s, s) uint8
            "depth": torch.from_numpy(d["depth"][rows].astype(np.float32)),  # (B, 1, s, s)
            "plan": torch.from_numpy(d["plan"][rows]),  # (B, P)
            "chunk": torch.from_numpy(d["teacher"][steps, :2]),  # (B, H, 2)
            "stop": torch.from_numpy((d["teacher"][rows, 2] > 0).astype(np.float32)),  # (B,)
        }

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        return self.batch(rng.choice(self.indices, size=batch_size))

    def ordered(self, batch_size: int):
        for i in range(0, len(self.indices), batch_size):
            yield self.batch(self.indices[i : i + batch_size])


def plans_without_s2(episode: np.ndarray, s1) -> np.ndarray:
    """(N, P) plan vectors S1 reads when it is never handed a plan (``s1.use_s2=false``):
    :class:`PlanMemory`'s empty vector at each frame's step in its episode (``episode`` (N,)
    ordered as in :class:`S1Batches`)."""
    starts = np.r_[True, episode[1:] != episode[:-1]]  # (N,)
    step = np.arange(len(episode)) - np.flatnonzero(starts)[np.cumsum(starts) - 1]  # (N,)
    memory = PlanMemory(s1.path_points)
    zero = np.zeros(3)
    return np.stack([memory.vector(zero, t) for t in range(int(step.max()) + 1)])[step]


def _validate(policy, batches: S1Batches, batch_size: int) -> dict[str, float]:
    """Mean losses on ``batches`` (on S1's device); the noise comes from fixed seeds in a
    forked RNG, so validations are comparable and the training randomness is untouched."""
    policy.s1.eval()
    device = next(policy.s1.parameters()).device
    sums: dict[str, float] = {}
    n = 0
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad(), torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        for batch in batches.ordered(batch_size):
            torch.manual_seed(int(torch.randint(0, 2**31 - 1, (1,), generator=gen)))
            out = policy.s1(to_device(batch, device))
            b = len(batch["stop"])
            for k, v in out.items():
                sums[k] = sums.get(k, 0.0) + float(v) * b
            n += b
    policy.s1.train()
    return {f"val_{k}": v / max(n, 1) for k, v in sums.items()}


def train_s1(
    init: str | Path,
    out: str | Path,
    data: Sequence[str | Path],
    steps: int = 3000,
    batch_size: int = 256,
    lr: float = 1e-3,
    weight_decay: float = 1e-4,
    seed: int = 0,
    settings: Sequence[str] = (),
    init_s1: bool = False,
    val_fraction: float = 0.1,
    eval_every: int = 250,
    compute: Compute = ON_CPU,
) -> dict:
    """Train S1 and write the agent with the best S1 to ``out``; returns the summary.

    ``compute``: the device and precision (:mod:`.part_training`); under torchrun every rank
    draws ``batch_size`` samples per step and rank 0 writes the agent."""
    torch.manual_seed(seed)
    policy, loaded, config = build_agent_from(
        init, "s1", settings, keep_part=init_s1, forced=["s1.kind=learned"]
    )
    s1_config = policy.config.s1
    arrays = load_s1_data(data, s1_config)
    if not s1_config.use_s2:  # the "without S2" ablation: S1 reads no plan, as at inference
        arrays["plan"] = plans_without_s2(arrays["episode"], s1_config)
    episodes = np.unique(arrays["episode"])
    if len(episodes) < 2:
        raise UserError(
            f"S1 data {[str(d) for d in data]} holds {len(episodes)} episode; whole episodes "
            "are held out for validation, so training needs at least 2 episodes"
        )
    rng = np.random.default_rng(seed)
    n_val = min(len(episodes) - 1, max(1, int(round(val_fraction * len(episodes)))))
    held = set(rng.permutation(episodes)[:n_val])
    is_val = np.isin(arrays["episode"], list(held))  # (N,)
    train = S1Batches(arrays, s1_config.head.horizon, np.flatnonzero(~is_val))
    val = S1Batches(arrays, s1_config.head.horizon, np.flatnonzero(is_val))
    log.info(
        "S1 data: %d train / %d val frames, %d stop labels",
        len(train.indices), len(val.indices), int((arrays["teacher"][:, 2] > 0).sum()),
    )  # fmt: skip
    policy.requires_grad_(False)
    policy.s1.requires_grad_(True)
    policy.s1.train()
    s1 = policy.s1
    trainer = PartTrainer(s1, lambda **batch: s1(batch)["loss"], compute, grad_clip=1.0)
    optimizer = build_optimizer(policy.s1, lr, weight_decay)
    scheduler = build_scheduler(optimizer, min(100, steps // 10), steps, 0.05)
    draws = rank_generator(rng, seed)
    best, best_state, history = np.inf, None, []
    t0 = time.perf_counter()
    for step in range(1, steps + 1):
        loss = trainer.step(train.sample(batch_size, draws), optimizer, scheduler)
        if step % eval_every == 0 or step == steps:
            row = {"step": step, "loss": loss, **_validate(policy, val, 512)}
            row["seconds"] = round(time.perf_counter() - t0, 1)
            history.append(row)
            log.info("S1 %s", json.dumps(row))
            if row["val_loss"] < best:
                best = row["val_loss"]
                best_state = {k: v.clone() for k, v in policy.s1.state_dict().items()}
    policy.s1.load_state_dict(best_state)
    policy.cpu()
    summary = {"best_val_loss": best, "history": history, "data": [str(d) for d in data]}
    write_agent(policy, loaded, config, out, {"s1_training": summary, "s1_steps": steps})
    log.info("wrote %s", out)
    return summary
