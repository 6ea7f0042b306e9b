"""Stages that train one part of a dual-system agent on top of a checkpoint: S1
(:mod:`.s1`) and S2's room-type classifier (:mod:`.room_type`).

Both read the agent of a checkpoint, change settings under one config key, train that part
with the rest loaded from the checkpoint, and write the whole agent as a new checkpoint
that ``vla-gr eval`` loads like any other.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from vla_gr.checkpoint import load_model_state, read_checkpoint
from vla_gr.errors import UserError

__all__ = ["build_agent_from", "graft_part", "write_agent"]


def build_agent_from(
    init: str | Path,
    part: str,
    settings: Sequence[str],
    keep_part: bool,
    forced: Sequence[str],
    part_config: Mapping | None = None,
):
    """The agent of checkpoint ``init`` with ``model.<part>`` replaced by ``part_config`` (if
    given), changed by ``settings`` (each ``key=value`` with a key under ``<part>.``) and then
    ``forced``; every weight is loaded from ``init`` except, unless ``keep_part``, those of
    ``part`` (fresh).

    Returns ``(policy, loaded checkpoint, its config with the merged model)``.
    """
    from omegaconf import OmegaConf

    from vla_gr.configs.model_schema import ModelConfig
    from vla_gr.policy.agent import VLAGRPolicy
    from vla_gr.policy.frames import apply_peft

    for item in settings:
        if "=" not in item or not item.split("=", 1)[0].strip().startswith(f"{part}."):
            raise UserError(f"setting {item!r} must be key=value with a key under {part}.")
    loaded = read_checkpoint(init)
    config = OmegaConf.create(loaded.config_yaml)
    if config.model.get("agent") != "dual_system":
        raise UserError(f"{init} is not a dual-system agent (model.agent={config.model.agent})")
    if part == "s1" and "s1" in config.model and "head" in config.model.s1:
        # the head's context width follows s1.dim: a saved width must not pin a new dim
        config.model.s1.head.context_dim = None
    merged = OmegaConf.merge(
        OmegaConf.structured(ModelConfig),
        config.model,
        {} if part_config is None else {part: part_config},
        OmegaConf.from_dotlist([*settings, *forced]),
    )
    policy = apply_peft(VLAGRPolicy(OmegaConf.to_object(merged)), merged.peft)
    prefix = f"{part}."
    fresh = {k: v for k, v in policy.state_dict().items() if k.startswith(prefix)}
    tensors = {k: v for k, v in loaded.model.items() if not k.startswith(prefix) or keep_part}
    load_model_state(policy, {**fresh, **tensors}, str(init))
    config.model = merged
    return policy, loaded, config


def write_agent(policy, loaded, config, out: str | Path, state_updates: dict) -> Path:
    """Write ``policy`` with ``config`` as checkpoint folder ``out`` (replaced), keeping the
    training state of ``loaded`` (without its RNG) plus ``state_updates``; verified by
    loading it back."""
    from omegaconf import OmegaConf

    from vla_gr.policy.export import write_checkpoint_folder

    tensors = {k: v.detach().contiguous() for k, v in policy.state_dict().items()}
    return write_checkpoint_folder(out, loaded, tensors, OmegaConf.to_yaml(config), state_updates)


def graft_part(
    init: str | Path, donor: str | Path, part: str, out: str | Path, settings: Sequence[str] = ()
) -> Path:
    """Write to ``out`` the agent of ``init`` with ``model.<part>`` and its weights taken from
    checkpoint ``donor`` (e.g. a room-type classifier trained beside another goal head).

    ``settings`` are ``model.*`` keys without the prefix, applied last
    (``navigator.room_reject_threshold=0.2``)."""
    from omegaconf import OmegaConf

    given = read_checkpoint(donor)
    donor_model = OmegaConf.create(given.config_yaml).model
    if part not in donor_model:
        raise UserError(f"{donor} has no model.{part} to take")
    policy, loaded, config = build_agent_from(
        init, part, [], keep_part=False, forced=[], part_config=donor_model[part]
    )
    prefix = f"{part}."
    tensors = {k[len(prefix) :]: v for k, v in given.model.items() if k.startswith(prefix)}
    if not tensors:
        raise UserError(f"{donor} holds no {part} weights")
    getattr(policy, part).load_state_dict(tensors)
    config.model = OmegaConf.merge(config.model, OmegaConf.from_dotlist(list(settings)))
    return write_agent(policy, loaded, config, out, {f"{part}_from": str(donor)})
