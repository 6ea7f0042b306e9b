"""Agents that ``vla-gr eval`` can run: a name -> factory registry.

An agent has ``reset(seed)`` (episode start; ``seed`` makes any randomness replayable),
``act(obs) -> float32 (3,)`` and ``parameters() -> {part: count}``. It may also set
``last_timings`` ({part: seconds} of its latest ``act``, e.g. ``{"s1": .., "s2": ..}``) so
that the harness reports latency per part; otherwise the whole ``act`` is one "decision".
An agent with a planner may have ``episode_summary() -> dict`` (e.g. its goal confidence),
kept in the episode's row under ``agent``.

A factory receives ``(cfg, env)``: the validated ``VLAGRConfig`` and the environment the
agent will run in, so that privileged agents (the geodesic expert) can read the world.
Later work registers more agents with :func:`register_agent`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from vla_gr.errors import UserError

log = logging.getLogger(__name__)

__all__ = [
    "AGENTS",
    "AgentError",
    "PolicyAgent",
    "as_env_action",
    "check_agent_name",
    "check_checkpoint",
    "make_agent",
    "register_agent",
]

AgentFactory = Callable[[object, object], object]
AGENTS: dict[str, AgentFactory] = {}


class AgentError(UserError, ValueError):
    """An agent that cannot be built: unknown name, missing or mismatched checkpoint."""


def register_agent(name: str) -> Callable[[AgentFactory], AgentFactory]:
    """Decorator: register ``factory(cfg, env) -> agent`` under ``name`` (unique)."""

    def wrap(factory: AgentFactory) -> AgentFactory:
        if name in AGENTS:
            raise ValueError(f"agent {name!r} is already registered")
        AGENTS[name] = factory
        return factory

    return wrap


def check_agent_name(name: str) -> None:
    """AgentError with the valid names when ``name`` is not registered."""
    if name not in AGENTS:
        raise AgentError(f"unknown agent {name!r}; valid agents: {', '.join(sorted(AGENTS))}")


def make_agent(name: str, cfg, env):
    """The agent ``name`` built for ``cfg`` and ``env``."""
    check_agent_name(name)
    return AGENTS[name](cfg, env)


def as_env_action(action) -> np.ndarray:
    """A policy action ``(1, A)`` or ``(A,)`` (tensor or array) -> float32 numpy ``(A,)``."""
    if isinstance(action, torch.Tensor):
        action = action.detach().float().cpu().numpy()
    action = np.asarray(action, dtype=np.float32)
    if action.ndim == 2 and action.shape[0] == 1:
        action = action[0]  # (A,)
    if action.ndim != 1:
        raise ValueError(f"policy action must be (A,) or (1, A); got shape {action.shape}")
    return action


def module_parameters(module: nn.Module) -> dict[str, int]:
    """Parameter count per top-level child of ``module`` plus ``total``."""
    parts = {
        name: sum(p.numel() for p in child.parameters()) for name, child in module.named_children()
    }
    parts = {k: v for k, v in parts.items() if v}
    parts["total"] = sum(p.numel() for p in module.parameters())
    return parts


class PolicyAgent:
    """Any object with ``reset()`` and ``select_action(obs) -> (1, A)`` (a ``VLAGRPolicy``).

    ``reset(seed)`` also seeds torch so that stochastic heads replay per episode.
    """

    def __init__(self, policy, device: torch.device | str = "cpu") -> None:
        self.policy = policy
        self.device = device

    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            torch.manual_seed(seed)
        self.policy.reset()

    def act(self, obs) -> np.ndarray:
        return as_env_action(self.policy.select_action(obs))  # (A,)

    @property
    def last_timings(self) -> dict[str, float] | None:
        """The policy's per-part seconds of its last decision (S1, S2), if it reports them."""
        return getattr(self.policy, "last_timings", None)

    def episode_summary(self) -> dict:
        """The dual system's goal confidence and last mode ({} for an end-to-end policy)."""
        system = getattr(self.policy, "dual_system", None)
        return system.episode_summary() if system is not None else {}

    def parameters(self) -> dict[str, int]:
        return module_parameters(self.policy) if isinstance(self.policy, nn.Module) else {}


class TrueMaskAgent:
    """The dual system with the TRUE goal mask as S2's perception (the planner's ceiling).

    Privileged: its goal likelihood is ``semantic == goal instance`` (needs the env's
    ``semantic`` observation); the navigator, its GR field, the S1 follower and the schedule
    come from ``cfg.model`` exactly as for the learned agent.
    """

    def __init__(self, cfg, env) -> None:
        from vla_gr.policy.dual_system import GroundedDualSystem

        self.env = env
        self.system = GroundedDualSystem.from_model_config(self._true_mask, cfg.model)

    def _true_mask(self, obs) -> np.ndarray:
        if "semantic" not in obs:
            raise AgentError("agent=true_mask needs the env's semantic observation")
        goal = int(self.env.unwrapped.goal.instance_id)
        return (np.asarray(obs["semantic"]) == goal).astype(np.float32)  # (H, W)

    def reset(self, seed: int | None = None) -> None:
        self.system.reset()

    def act(self, obs) -> np.ndarray:
        return self.system.step(obs)  # (3,)

    @property
    def last_timings(self) -> dict[str, float]:
        return self.system.last_timings

    def episode_summary(self) -> dict:
        return self.system.episode_summary()

    def parameters(self) -> dict[str, int]:
        return {}


class ExpertAgent:
    """The privileged geodesic expert (knows the goal's position)."""

    def __init__(self, cfg, env) -> None:
        from vla_gr.envs.expert import GeodesicExpert

        self.expert = GeodesicExpert(env)

    def reset(self, seed: int | None = None) -> None:
        self.expert.reset()

    def act(self, obs) -> np.ndarray:
        return np.asarray(self.expert.act(obs), dtype=np.float32)

    def parameters(self) -> dict[str, int]:
        return {}


class RandomAgent:
    """Uniform random velocities; STOP with probability ``stop_prob`` per step."""

    def __init__(self, stop_prob: float = 0.01) -> None:
        self.stop_prob = stop_prob
        self.rng = np.random.default_rng(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs) -> np.ndarray:
        v, w = self.rng.uniform(-1.0, 1.0, 2)
        stop = 1.0 if self.rng.random() < self.stop_prob else -1.0
        return np.array([v, w, stop], dtype=np.float32)

    def parameters(self) -> dict[str, int]:
        return {}


# ----------------------------------------------------------------------------- checkpoints

_MATCHED = (
    ("model.image_size", "env.image_size"),
    ("model.encoders.max_depth", "env.max_depth"),
    ("model.goal_head.max_depth", "env.max_depth"),
)
_SAME = ("env.control_hz",)


def _get(tree, dotted: str):
    for key in dotted.split("."):
        if tree is None or key not in tree:
            return None
        tree = tree[key]
    return tree


def check_checkpoint(cfg) -> None:
    """AgentError naming the problem when ``eval.checkpoint`` cannot drive this eval's env.

    Checks the path exists, the checkpoint verifies, its model config is one this version
    reads, and its observation settings (image size, depth range, control rate) match.
    """
    from omegaconf import OmegaConf

    from vla_gr import __version__
    from vla_gr.checkpoint import CheckpointError, read_checkpoint
    from vla_gr.configs.model_schema import ModelConfig

    path = cfg.eval.checkpoint
    if not path:
        raise AgentError("agent=checkpoint needs checkpoint=<run>/checkpoints/best")
    if not Path(path).exists():
        raise AgentError(f"checkpoint {path} does not exist")
    try:
        loaded = read_checkpoint(path, verify=False)
    except CheckpointError as err:
        raise AgentError(str(err)) from None
    saved = OmegaConf.to_container(OmegaConf.create(loaded.config_yaml))
    version = loaded.state.get("vla_gr_version", "unknown")
    here = OmegaConf.structured(cfg)
    for model_key, env_key in _MATCHED:
        want, have = _get(saved, model_key), OmegaConf.select(here, env_key)
        if want is not None and want != have:
            raise AgentError(
                f"checkpoint {path} was trained with {model_key}={want}, this eval has "
                f"{env_key}={have}; pass {env_key}={want}"
            )
    for key in _SAME:
        want, have = _get(saved, key), OmegaConf.select(here, key)
        if want is not None and want != have:
            raise AgentError(
                f"checkpoint {path} was trained with {key}={want}, this eval has {key}={have}"
            )
    try:
        OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(ModelConfig), saved["model"]))
    except Exception as err:  # noqa: BLE001 - any schema failure is the same user problem
        first = str(err).strip().splitlines()[0]
        raise AgentError(
            f"checkpoint {path} (vla-gr {version}) has a model config this version "
            f"({__version__}) cannot read: {first}"
        ) from None
    if version != __version__:
        log.warning(
            "checkpoint %s was written by vla-gr %s, this is %s", path, version, __version__
        )


@register_agent("checkpoint")
def _checkpoint_agent(cfg, env) -> PolicyAgent:
    from vla_gr.checkpoint import CheckpointError
    from vla_gr.policy import VLAGRPolicy

    check_checkpoint(cfg)
    try:
        policy = VLAGRPolicy.from_pretrained(
            cfg.eval.checkpoint, device=cfg.eval.device, overrides=cfg.eval.model_overrides
        )
    except CheckpointError as err:
        raise AgentError(str(err)) from None
    return PolicyAgent(policy.eval(), cfg.eval.device)


@register_agent("expert")
def _expert_agent(cfg, env) -> ExpertAgent:
    return ExpertAgent(cfg, env)


@register_agent("true_mask")
def _true_mask_agent(cfg, env) -> TrueMaskAgent:
    return TrueMaskAgent(cfg, env)


@register_agent("random")
def _random_agent(cfg, env) -> RandomAgent:
    return RandomAgent()
