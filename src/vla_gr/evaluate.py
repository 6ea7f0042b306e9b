"""Closed-loop evaluation: run a policy on ``VLAGR/ObjectNav-v0`` episodes, average the metrics.

``rollout_policy`` is the loop habitat-lab / LeRobot eval scripts run: reset the env on an
episode, reset the policy, feed each observation to ``policy.select_action`` until the episode
terminates (STOP) or is truncated (step budget), keep the final ``info``. ``summarize``
averages those infos with :func:`vla_gr.envs.metrics.aggregate`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from vla_gr.envs.metrics import aggregate

log = logging.getLogger(__name__)

__all__ = ["rollout_policy", "summarize"]


def _as_env_action(action) -> np.ndarray:
    """A policy action ``(1, A)`` or ``(A,)`` (tensor or array) -> float32 numpy ``(A,)``."""
    if isinstance(action, torch.Tensor):
        action = action.detach().float().cpu().numpy()
    action = np.asarray(action, dtype=np.float32)
    if action.ndim == 2 and action.shape[0] == 1:
        action = action[0]  # (A,)
    if action.ndim != 1:
        raise ValueError(f"policy action must be (A,) or (1, A); got shape {action.shape}")
    return action


def rollout_policy(
    policy,
    env_kwargs: dict,
    episodes: Sequence[int],
    device: torch.device | str = "cpu",
) -> list[dict]:
    """Run ``policy`` on each episode index of ``episodes``; one final info dict per episode.

    ``policy`` needs ``reset()`` and ``select_action(obs) -> (1, A)``; an ``nn.Module`` is
    moved to ``device`` and put in eval mode for the rollout (its train/eval mode is restored
    afterwards). ``env_kwargs`` go to ``gymnasium.make("VLAGR/ObjectNav-v0", ...)``
    (``max_episode_steps`` is the step budget). Episode ``k`` is ``env.reset(seed=k)``.
    """
    from vla_gr.data.collect import make_env

    if len(episodes) == 0:
        raise ValueError("episodes must name at least one episode index")
    is_module = isinstance(policy, nn.Module)
    was_training = policy.training if is_module else False
    if is_module:
        policy.to(device).eval()
    env = make_env(dict(env_kwargs))
    infos: list[dict] = []
    try:
        with torch.inference_mode():
            for k in episodes:
                obs, info = env.reset(seed=int(k))
                policy.reset()
                done = False
                while not done:
                    action = _as_env_action(policy.select_action(obs))  # (A,)
                    obs, _, terminated, truncated, info = env.step(action)
                    done = terminated or truncated
                infos.append(dict(info, episode_index=int(k)))
                log.debug(
                    "episode %d: success %.0f spl %.3f in %d steps",
                    k,
                    info["success"],
                    info["spl"],
                    info["steps"],
                )
    finally:
        env.close()
        if is_module:
            policy.train(was_training)
    return infos


def summarize(infos: Sequence[dict]) -> dict:
    """Mean success, SPL, soft-SPL, collision rate, path length, final distance; ``episodes``."""
    return aggregate(infos)
