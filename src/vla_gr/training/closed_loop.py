"""Training-time closed-loop validation and the score that picks the ``best`` checkpoint.

At each validation rank 0 runs the (EMA) policy on ``training.eval_episodes`` fixed ``val``
episodes (indices 0..N-1, so successive evaluations are comparable) and the other ranks
wait; the metrics are then broadcast so every rank takes the same checkpoint decision. Rank 0
also gets videos of the first ``training.eval_videos`` episodes (for TensorBoard).
Called by ``maybe_validate`` in ``vla_gr.train``, which hands in the rollout (the eval
harness's episode loop): training imports no evaluation code.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping

import numpy as np
import torch

from vla_gr.training.distributed import DistInfo, barrier

log = logging.getLogger(__name__)

LOGGED = ("success", "spl", "soft_spl", "collision_rate")
WORST = (-math.inf, -math.inf)


#: A video: frames (each (H, W, 3) uint8) and frames per second.
Clip = tuple[list[np.ndarray], float]
#: ``(policy, env kwargs, episode indices, device, videos) -> ({metric: mean} over those
#: episodes, {tag: clip} of the first ``videos`` episodes)``.
Rollout = Callable[
    [object, dict, Iterable[int], torch.device, int], tuple[Mapping[str, float], dict[str, Clip]]
]


def closed_loop_metrics(
    model, cfg, dist: DistInfo, amp_context, rollout: Rollout
) -> tuple[dict[str, float], dict[str, Clip]]:
    """``val/<metric>`` of ``model`` on ``cfg.training.eval_episodes`` episodes ({} when off)
    and, on rank 0 with TensorBoard on, videos of the first ``training.eval_videos`` of them.

    ``amp_context`` is a zero-argument callable returning the autocast context to run in;
    ``rollout`` runs the episodes, averages their metrics and films the first ones.
    """
    t = cfg.training
    if t.eval_episodes <= 0:
        return {}, {}
    out: list = [None]
    clips: dict[str, Clip] = {}
    if dist.is_main:
        from vla_gr.data.collect import env_kwargs_from_config

        env_kwargs = env_kwargs_from_config(cfg, "val", semantic=False)
        env_kwargs["max_episode_steps"] = t.eval_max_steps
        videos = min(t.eval_videos, t.eval_episodes) if cfg.logging.tensorboard else 0
        t0 = time.perf_counter()
        with amp_context():
            summary, clips = rollout(model, env_kwargs, range(t.eval_episodes), dist.device, videos)
        out[0] = {f"val/{k}": float(summary[k]) for k in LOGGED}
        out[0]["val/eval_seconds"] = time.perf_counter() - t0
    if dist.distributed:
        barrier()
        torch.distributed.broadcast_object_list(out, src=0)
    return out[0], clips


def best_score(metric: str, val_loss: float, evals: Mapping[str, float]) -> tuple[float, float]:
    """Higher is better: ``(-val_loss, 0)`` or ``(val/<metric>, -val_loss)`` (ties: lower loss).

    A missing (NaN) loss counts as the worst tie-breaker.
    """
    neg_loss = -val_loss if not math.isnan(val_loss) else -math.inf
    if metric == "val_loss":
        return (neg_loss, 0.0)
    return (float(evals[f"val/{metric}"]), neg_loss)


def score_to_json(score: tuple[float, float]) -> list[float | None]:
    """JSON-safe copy of a score (non-finite entries -> None)."""
    return [v if math.isfinite(v) else None for v in score]


def score_from_state(state: Mapping, metric: str) -> tuple[float, float]:
    """The best score saved in a trainer state for ``metric``; WORST when there is none.

    Checkpoints written before closed-loop validation hold only ``best_val_loss``; it is the
    score when ``metric`` is ``val_loss``. A checkpoint scored by another metric restarts the
    tracking (with a warning).
    """
    saved_metric = state.get("best_metric", "val_loss")
    if saved_metric != metric:
        log.warning("checkpoint picked `best` by %s, this run by %s: restart", saved_metric, metric)
        return WORST
    if state.get("best_score") is not None:
        a, b = (-math.inf if v is None else float(v) for v in state["best_score"])
        return (a, b)
    if metric == "val_loss" and state.get("best_val_loss") is not None:
        return (-float(state["best_val_loss"]), 0.0)
    return WORST
