"""Agents that ``vla-gr eval`` can run: a name -> factory registry.

An agent (an :class:`EvalAgent`) has ``reset(seed)`` (episode start; ``seed`` makes any
randomness replayable), ``act(obs) -> float32 (3,)``, ``parameters() -> {part: count}``,
``last_timings`` ({part: seconds} of its latest ``act``, e.g. ``{"s1": .., "s2": ..}``; {}:
the whole ``act`` is one "decision"), ``episode_summary() -> dict`` (e.g. its goal
confidence; kept in the episode's row under ``agent``), ``declared_outcome`` (the outcome it
declared instead of acting, e.g. ``"not_understood"``; None while it acts: the episode loop
then calls ``env.unwrapped.declare(outcome)`` instead of ``env.step``) and ``reading() -> dict
| None`` (how it read the request, kept in the row under ``reading``; None without a reader).

A factory receives ``(cfg, env)``: the validated ``VLAGRConfig`` and the environment the
agent will run in, so that privileged agents (the geodesic expert) can read the world.
Later work registers more agents with :func:`register_agent`.

A *variant* (``eval.variants.<name>``, :class:`~vla_gr.configs.schema.VariantConfig`) is a
named agent made of a registered one (``checkpoint``, ``true_mask`` or ``true_category``), a
checkpoint and
inference-only overrides; :func:`resolve_agent` turns any agent name into the registered
agent and the config it is built with, in the main process and in every worker alike.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from types import MappingProxyType

import numpy as np
import torch
from torch import nn

from vla_gr.errors import UserError

log = logging.getLogger(__name__)

__all__ = [
    "AGENTS",
    "AgentError",
    "EvalAgent",
    "PolicyAgent",
    "as_env_action",
    "agent_checkpoint",
    "check_agent",
    "check_agent_name",
    "check_checkpoint",
    "checkpoint_policy",
    "make_agent",
    "register_agent",
    "resolve_agent",
]

AgentFactory = Callable[[object, object], object]
AGENTS: dict[str, AgentFactory] = {}
#: Agents that run a checkpoint's dual system on privileged S2 perception (their ceilings).
PRIVILEGED_S2 = ("true_mask", "true_category")


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


def check_agent_name(name: str, variants=()) -> None:
    """AgentError with the valid names when ``name`` is neither registered nor a variant."""
    if name not in AGENTS and name not in variants:
        raise AgentError(
            f"unknown agent {name!r}; valid agents: {', '.join(sorted(AGENTS))}; "
            f"variants: {', '.join(variants) or 'none'}"
        )


def resolve_agent(name: str, cfg) -> tuple[str, object]:
    """(registered agent, the config it is built with) of a registered agent or a variant.

    A variant builds its ``agent`` with ``eval.checkpoint`` = its checkpoint (None: the
    eval's) and ``eval.model_overrides`` = its overrides.
    """
    variants = cfg.eval.variants
    clash = [v for v in variants if v in AGENTS]
    if clash:
        raise AgentError(
            f"eval.variants.{clash[0]} has the name of a registered agent; rename the variant"
        )
    check_agent_name(name, variants)
    if name in AGENTS:
        return name, cfg
    v = variants[name]
    sub = dataclasses.replace(
        cfg.eval,
        checkpoint=v.checkpoint or cfg.eval.checkpoint,
        model_overrides=list(v.model_overrides),
    )
    return v.agent, dataclasses.replace(cfg, eval=sub)


def agent_checkpoint(base: str, cfg) -> str | None:
    """The checkpoint that registered agent ``base`` loads under ``cfg`` (None: none)."""
    return cfg.eval.checkpoint if base in ("checkpoint", *PRIVILEGED_S2) else None


def check_agent(name: str, cfg) -> None:
    """Refuse an unknown agent or a checkpoint (with its overrides) that cannot drive this
    eval's env, before any episode runs; a variant's error names it (and its ``made_by``)."""
    base, sub = resolve_agent(name, cfg)
    try:
        if base == "checkpoint":
            checkpoint_policy(sub)
        elif base == "true_mask":
            true_mask_policy(sub)
        elif base == "true_category":
            checkpoint_policy(sub, dual_system=True, agent=base)
    except AgentError as err:
        if name in AGENTS:
            raise
        path, made_by = sub.eval.checkpoint, cfg.eval.variants[name].made_by
        hint = f"; make it with: {made_by}" if made_by and path and not Path(path).exists() else ""
        raise AgentError(f"agent {name}: {err}{hint}") from None


def make_agent(name: str, cfg, env):
    """The agent ``name`` (registered or a variant) built for ``cfg`` and ``env``."""
    base, sub = resolve_agent(name, cfg)
    return AGENTS[base](sub, env)


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


class EvalAgent:
    """Base of the eval agents: no parts timed, nothing to summarise, no parameters."""

    def reset(self, seed: int | None = None) -> None:
        """Episode start; ``seed`` makes any randomness replayable."""

    def act(self, obs) -> np.ndarray:
        """One action float32 (3,) for one env observation."""
        raise NotImplementedError

    #: seconds per part of the latest ``act`` (empty: one part, the decision); an agent that
    #: times its parts sets or overrides it
    last_timings: Mapping[str, float] = MappingProxyType({})

    def episode_summary(self) -> dict:
        """What the agent concluded this episode, kept in its row."""
        return {}

    @property
    def declared_outcome(self) -> str | None:
        """The outcome the agent declared after its latest ``act`` instead of acting (one of
        ``vla_gr.envs.DECLARED_OUTCOMES``; that action was no STOP); None while it acts."""
        return None

    def reading(self) -> dict | None:
        """How the agent read this episode's request (``Reading.as_dict()``: fields,
        confidences, unknown words, understood, reason); None for an agent without a reader."""
        return None

    def parameters(self) -> dict[str, int]:
        """Parameter count per part plus ``total`` ({} without networks)."""
        return {}


class PolicyAgent(EvalAgent):
    """A navigation policy (``reset()``, ``select_action(obs) -> (A,)``,
    ``episode_summary()``, ``last_timings``, ``declared_outcome``, ``reading``) as an eval
    agent.

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
    def last_timings(self) -> dict[str, float]:
        """The policy's per-part seconds of its last decision (S1, S2; {}: one part)."""
        return self.policy.last_timings

    def episode_summary(self) -> dict:
        """What the policy concluded (the dual system's goal confidence, last mode, how S2
        read the instruction, ...; {} for an end-to-end policy)."""
        return self.policy.episode_summary()

    @property
    def declared_outcome(self) -> str | None:
        """The policy's declared outcome (``NavigationPolicy.declared_outcome``)."""
        return self.policy.declared_outcome

    def reading(self) -> dict | None:
        """The policy's reading of the request as a dict (None when it has none)."""
        reading = self.policy.reading
        return None if reading is None else reading.as_dict()

    def parameters(self) -> dict[str, int]:
        return module_parameters(self.policy) if isinstance(self.policy, nn.Module) else {}


class UntrainedDualSystemAgent(EvalAgent):
    """``cfg.model``'s dual system without a checkpoint or networks, driven by a privileged
    perception (the true mask): the navigator, its GR field and the pure-pursuit S1."""

    def __init__(self, system) -> None:
        self.system = system

    def reset(self, seed: int | None = None) -> None:
        self.system.reset()

    def act(self, obs) -> np.ndarray:
        return self.system.step(obs)  # (3,)

    @property
    def last_timings(self) -> dict[str, float]:
        return self.system.last_timings

    def episode_summary(self) -> dict:
        return self.system.episode_summary()

    @property
    def declared_outcome(self) -> str | None:
        """The dual system's declared outcome (a request not understood)."""
        return self.system.declared_outcome

    def reading(self) -> dict | None:
        """The dual system's reading of the request as a dict (None when it has none)."""
        reading = self.system.reading
        return None if reading is None else reading.as_dict()


def true_mask_agent(cfg, env) -> PolicyAgent | UntrainedDualSystemAgent:
    """The dual system with the TRUE goal mask as S2's perception (the planner's ceiling).

    Privileged: its goal likelihood is ``semantic == goal instance`` (needs the env's
    ``semantic`` observation). The navigator, its GR field, the S1 follower (learned or pure
    pursuit) and the schedule are ``eval.checkpoint``'s (with ``eval.model_overrides``) when
    one is given, else ``cfg.model``'s, exactly as for the learned agent.
    """
    from vla_gr.agent.dual_system import GroundedDualSystem
    from vla_gr.agent.perception.percept import TrueMaskPerception

    perception = TrueMaskPerception(env)
    policy = true_mask_policy(cfg)
    if policy is None:
        system = GroundedDualSystem.from_model_config(perception, cfg.model)
        return UntrainedDualSystemAgent(system)
    policy.use_perception(perception)
    return PolicyAgent(policy, cfg.eval.device)


def true_mask_policy(cfg):
    """``eval.checkpoint``'s dual system (with ``eval.model_overrides``) for the true-mask
    agent; None without a checkpoint (``cfg.model``'s untrained dual system drives)."""
    if cfg.eval.checkpoint:
        return checkpoint_policy(cfg, dual_system=True)
    if cfg.eval.model_overrides:
        raise AgentError(
            "agent=true_mask applies model_overrides to a checkpoint's dual system; "
            "give checkpoint=<run>/checkpoints/best"
        )
    return None


def true_category_agent(cfg, env) -> PolicyAgent:
    """The learned goal head with its pixels gated by the TRUE category mask (privileged).

    S2's likelihood is the goal head's, zeroed on pixels that do not show an object of the
    goal's category (from the env's ``semantic`` observation): the goal head still has to pick
    the instructed instance among same-category ones, but never fires on another category.
    Between ``checkpoint`` and ``true_mask`` it tells how much of the gap is category
    recognition. Needs a dual-system ``eval.checkpoint`` (with ``eval.model_overrides``); its
    room and object checks and its instruction reader, if it has them, run as in the
    checkpoint's agent.
    """
    from vla_gr.agent.perception.percept import TrueCategoryGate

    if not cfg.eval.checkpoint:
        raise AgentError("agent=true_category gates a checkpoint's goal head; give checkpoint=")
    policy = checkpoint_policy(cfg, dual_system=True, agent="true_category")
    policy.use_perception(policy.learned_perception().gated(TrueCategoryGate(env)))
    return PolicyAgent(policy, cfg.eval.device)


class ExpertAgent(EvalAgent):
    """The privileged geodesic expert (knows the goal's position)."""

    def __init__(self, cfg, env) -> None:
        from vla_gr.envs.expert import GeodesicExpert

        self.expert = GeodesicExpert(env)

    def reset(self, seed: int | None = None) -> None:
        self.expert.reset()

    def act(self, obs) -> np.ndarray:
        return np.asarray(self.expert.act(obs), dtype=np.float32)


class RandomAgent(EvalAgent):
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


def check_checkpoint(cfg, path: str | None) -> None:
    """AgentError naming the problem when checkpoint ``path`` cannot drive this eval's env.

    Checks the path exists, the checkpoint verifies, its model config is one this version
    reads, and its observation settings (image size, depth range, control rate) match.
    """
    from omegaconf import OmegaConf

    from vla_gr import __version__
    from vla_gr.checkpoint import CheckpointError, read_checkpoint
    from vla_gr.policy.factory import checkpoint_model_config

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
        checkpoint_model_config(loaded.config_yaml, path, config_file=loaded.config_file)
    except CheckpointError as err:
        raise AgentError(str(err)) from None
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


def checkpoint_policy(cfg, dual_system: bool = False, agent: str = "true_mask"):
    """The policy of ``eval.checkpoint`` with ``eval.model_overrides`` on ``eval.device``,
    checked first (:func:`check_checkpoint`); AgentError when it cannot be built (or is not
    a dual system when ``dual_system``; ``agent`` names who needs one)."""
    from omegaconf.errors import OmegaConfBaseException

    from vla_gr.checkpoint import CheckpointError
    from vla_gr.policy import VLAGRPolicy, load_policy

    path, overrides = cfg.eval.checkpoint, list(cfg.eval.model_overrides)
    check_checkpoint(cfg, path)
    expected = VLAGRPolicy if dual_system else None
    try:
        policy = load_policy(path, cfg.eval.device, overrides, expected=expected)
    except CheckpointError as err:
        if dual_system and "holds model.agent" in str(err):
            raise AgentError(f"{err}; agent={agent} needs a dual-system checkpoint") from None
        raise AgentError(str(err)) from None
    except UserError as err:
        raise AgentError(str(err)) from None
    except (ValueError, OmegaConfBaseException) as err:
        first = str(err).strip().splitlines()[0]
        raise AgentError(f"model_overrides={overrides} do not apply to {path}: {first}") from None
    return policy.eval()


@register_agent("checkpoint")
def _checkpoint_agent(cfg, env) -> PolicyAgent:
    return PolicyAgent(checkpoint_policy(cfg), cfg.eval.device)


@register_agent("expert")
def _expert_agent(cfg, env) -> ExpertAgent:
    return ExpertAgent(cfg, env)


register_agent("true_mask")(true_mask_agent)


register_agent("true_category")(true_category_agent)


@register_agent("random")
def _random_agent(cfg, env) -> RandomAgent:
    return RandomAgent()
