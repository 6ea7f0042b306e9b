"""One class per agent, chosen by ``model.agent`` (LeRobot's ``policies/factory.py``).

- :func:`make_policy` builds the class of ``config.agent`` from a ``ModelConfig``;
- :func:`load_policy` reads a self-contained checkpoint folder and builds the class its
  ``config.yaml`` names. Loading never fills a model setting from a code default: a
  checkpoint whose ``model`` section lacks a key of this version, or has one this version
  does not know, is refused in one line naming the key.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch

from vla_gr.checkpoint import CONFIG_FILE, CheckpointError, load_model_state, read_checkpoint
from vla_gr.configs.model_schema import ModelConfig
from vla_gr.errors import ConfigError
from vla_gr.policy.base import NavigationPolicy
from vla_gr.policy.end_to_end import EndToEndPolicy
from vla_gr.policy.frames import apply_peft
from vla_gr.policy.vla_gr import VLAGRPolicy

__all__ = [
    "INFERENCE_SETTINGS",
    "POLICY_CLASSES",
    "REMOVED_KEYS",
    "RENAMED_KEYS",
    "checkpoint_model_config",
    "load_policy",
    "make_policy",
    "model_key_gaps",
    "policy_class",
    "require_agent",
]

#: ``model.agent`` -> the class that is that agent.
POLICY_CLASSES: dict[str, type[NavigationPolicy]] = {
    "dual_system": VLAGRPolicy,
    "end_to_end": EndToEndPolicy,
}
#: Model keys (under ``model.``) renamed since checkpoints were first written: old -> new.
#: A checkpoint or an override with an old key fails naming the new one; a migration
#: (``vla-gr export SRC DST --rename-keys``) writes the new names.
RENAMED_KEYS: dict[str, str] = {
    # the navigator, one section per concern (vla_gr.agent.navigator.config)
    "navigator.look_around_angle": "navigator.look_around.angle",
    "navigator.look_around_completes": "navigator.look_around.completes",
    "navigator.pixel_threshold": "navigator.confirmation.pixel_threshold",
    "navigator.visible_threshold": "navigator.confirmation.visible_threshold",
    "navigator.confirm_ticks": "navigator.confirmation.ticks",
    "navigator.min_goal_pixels": "navigator.confirmation.min_goal_pixels",
    "navigator.room_reject_threshold": "navigator.goal_checks.room_reject_threshold",
    "navigator.room_ticks": "navigator.goal_checks.room_ticks",
    "navigator.object_reject_threshold": "navigator.goal_checks.object_reject_threshold",
    "navigator.object_ticks": "navigator.goal_checks.object_ticks",
    "navigator.relation_distance": "navigator.goal_checks.relation_distance",
    "navigator.anchor_outvotes_goal": "navigator.goal_checks.anchor_outvotes_goal",
    "navigator.goal_yields_to_anchor": "navigator.goal_checks.goal_yields_to_anchor",
    "navigator.anchor_ticks": "navigator.goal_checks.anchor_ticks",
    "navigator.stop_distance": "navigator.approach.stop_distance",
    "navigator.stop_distance_at_end": "navigator.approach.stop_distance_at_end",
    "navigator.path_end_distance": "navigator.approach.path_end_distance",
    "navigator.goal_halo_cells": "navigator.approach.goal_halo_cells",
    "navigator.stop_visible_threshold": "navigator.approach.stop_visible_threshold",
    "navigator.verify_steps": "navigator.approach.verify_steps",
    "navigator.dead_end_steps": "navigator.approach.dead_end_steps",
    "navigator.unreachable_steps": "navigator.approach.unreachable_steps",
    "navigator.blocked_steps": "navigator.recovery.blocked_steps",
    "navigator.blocked_distance": "navigator.recovery.blocked_distance",
    "navigator.drive_bearing": "navigator.recovery.drive_bearing",
    "navigator.stuck_steps": "navigator.recovery.stuck_steps",
    "navigator.stuck_distance": "navigator.recovery.stuck_distance",
    "navigator.recover_back_steps": "navigator.recovery.back_steps",
    "navigator.recover_turn_steps": "navigator.recovery.turn_steps",
    "navigator.recover_back_speed": "navigator.recovery.back_speed",
    "navigator.virtual_obstacle_distance": "navigator.recovery.virtual_obstacle_distance",
    "navigator.virtual_obstacle_radius": "navigator.recovery.virtual_obstacle_radius",
    "navigator.no_path_steps": "navigator.recovery.no_path_steps",
    "navigator.path_hold_steps": "navigator.recovery.path_hold_steps",
    "navigator.trap_recoveries": "navigator.traps.recoveries",
    "navigator.trap_rejects_goal": "navigator.traps.rejects_goal",
    "navigator.trap_radius": "navigator.traps.radius",
    "navigator.trap_obstacle_radius": "navigator.traps.obstacle_radius",
    "navigator.tight_radius": "navigator.tight.radius",
    "navigator.tight_steps": "navigator.tight.steps",
    "navigator.tight_speed": "navigator.tight.speed",
    "navigator.local_planner": "navigator.local_planner.enabled",
    "navigator.local_cell": "navigator.local_planner.cell",
    "navigator.local_window": "navigator.local_planner.window",
    "navigator.local_margin": "navigator.local_planner.margin",
    "navigator.local_start_radius": "navigator.local_planner.start_radius",
    "navigator.local_clearance_cost": "navigator.local_planner.clearance_cost",
    "navigator.local_min_progress": "navigator.local_planner.min_progress",
    "navigator.local_replan_ticks": "navigator.local_planner.replan_ticks",
    "navigator.local_off_path": "navigator.local_planner.off_path",
    "navigator.local_min_hits": "navigator.local_planner.min_hits",
    "navigator.virtual_obstacle_hits": "navigator.map_edits.obstacle_hits",
    "navigator.noise_max_hits": "navigator.map_edits.noise_max_hits",
    "navigator.noise_free_ratio": "navigator.map_edits.noise_free_ratio",
    "navigator.visited_clear_radius": "navigator.map_edits.visited_clear_radius",
    # one key per setting: the drive test reads the follower's own lookahead (the two were
    # always equal); a migration refuses a checkpoint where they differ
    "navigator.pursuit_lookahead": "pursuit.lookahead",
    # the agent's schedule, apart from the seed's DualSystemArchitecture
    "dual_system.planning_frequency_hz": "schedule.planning_frequency_hz",
    "dual_system.control_frequency_hz": "schedule.control_frequency_hz",
}
_SEED_BLOCK = "configured the seed's latent DualSystemArchitecture, which no agent runs"
#: Model keys removed since checkpoints were first written: key -> why. A migration
#: (``vla-gr export SRC DST --rename-keys``) drops them.
REMOVED_KEYS: dict[str, str] = {
    f"dual_system.{key}": _SEED_BLOCK
    for key in (
        "visual_dim", "vlm_dim", "s1_hidden_dim", "s2_hidden_dim", "action_dim", "proprio_dim",
        "goal_dim", "num_subgoals", "s1_num_layers", "s2_num_layers", "s2_num_heads", "dropout",
        "gate",
    )
}  # fmt: skip
_LEXICON = "said requests again in template words; the instruction reader reads them now"
REMOVED_KEYS |= {
    f"instruction_lexicon.{key}": _LEXICON
    for key in (
        "enabled", "word_senses", "locative_senses", "place_senses", "clause_places",
        "noun_heads", "room_margin", "room_threshold", "category_margin", "colors",
        "categories", "room_types",
    )
}  # fmt: skip
REMOVED_KEYS["instruction_reader.fields"] = "chose the fields of the old reader; it reads all"
#: Model settings a loaded checkpoint may change (no weight depends on them): the planner,
#: its GR field, which S1 drives and how it samples, the follower, the S2 schedule, the goal
#: head's inference options (category gate, test-time flip), the segmenter's relation
#: candidates and the engine that runs the perception networks.
INFERENCE_SETTINGS = (
    "navigator.",
    "pursuit.",
    "gr_field.",
    "instruction_reader.temperature",
    "instruction_reader.min_confidence",
    "schedule.planning_frequency_hz",
    "goal_head.category_gate",
    "goal_head.test_time_flip",
    "object_category.relation_candidates",
    "object_category.anchor_not_goal",
    "perception.engine",
    "s1.kind",
    "s1.use_s2",
    "s1.depth_guard",
    "s1.stop_threshold",
    "s1.n_action_steps",
    "s1.head.num_inference_steps",
    "s1.head.sampler",
)


def policy_class(agent: str) -> type[NavigationPolicy]:
    """The class of agent kind ``agent`` (``model.agent``); ConfigError naming the choices."""
    if agent not in POLICY_CLASSES:
        raise ConfigError(f"model.agent={agent!r}; valid agents: {', '.join(POLICY_CLASSES)}")
    return POLICY_CLASSES[agent]


def require_agent(agent: str, expected: type[NavigationPolicy], source) -> type[NavigationPolicy]:
    """The class of ``agent`` when it is an ``expected``; CheckpointError naming ``source``
    (a checkpoint) and the agent it holds otherwise."""
    cls = policy_class(agent)
    if not issubclass(cls, expected):
        raise CheckpointError(
            f"checkpoint {source} holds model.agent={agent} ({cls.__name__}), not a "
            f"{expected.__name__}"
        )
    return cls


def make_policy(config: ModelConfig) -> NavigationPolicy:
    """A new (untrained) agent of the kind ``config.agent``."""
    return policy_class(config.agent)(config)


def _leaf_keys(tree: Mapping, prefix: str = "") -> set[str]:
    """Dotted keys of the leaves of a nested mapping (lists and empty mappings are leaves)."""
    keys: set[str] = set()
    for key, value in tree.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            keys |= _leaf_keys(value, dotted + ".")
        else:
            keys.add(dotted)
    return keys


def model_key_gaps(saved: Mapping) -> tuple[list[str], list[str]]:
    """(keys of this version's ``ModelConfig`` that ``saved`` lacks, keys of ``saved`` it does
    not know), dotted below ``model.``, sorted."""
    from omegaconf import OmegaConf

    schema = OmegaConf.to_container(OmegaConf.structured(ModelConfig))
    want, have = _leaf_keys(schema), _leaf_keys(saved)
    return sorted(want - have), sorted(have - want)


_MIGRATE = "vla-gr export SRC DST --rename-keys"


def _check_keys(saved: Mapping, path, config_file: str = CONFIG_FILE) -> None:
    """CheckpointError in one line when ``saved`` (a checkpoint's ``model`` section, from its
    ``config_file``) lacks a key of this version's ``ModelConfig`` or has one it does not know
    (naming the new key of a renamed one)."""
    missing, unknown = model_key_gaps(saved)
    section = "model." if config_file == CONFIG_FILE else ""  # config.json is the section
    for old in unknown:
        if old in RENAMED_KEYS:
            raise CheckpointError(
                f"checkpoint {path}: model.{old} was renamed model.{RENAMED_KEYS[old]}; "
                f"write the new names with {_MIGRATE}"
            )
    for old in unknown:
        if old in REMOVED_KEYS:
            raise CheckpointError(
                f"checkpoint {path}: model.{old} was removed (it {REMOVED_KEYS[old]}); "
                f"drop it with {_MIGRATE}"
            )
    if unknown:
        more = f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""
        raise CheckpointError(
            f"checkpoint {path}: {config_file} has {section}{unknown[0]}{more}, which this "
            "version does not know"
        )
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise CheckpointError(
            f"checkpoint {path}: {config_file} lacks {section}{missing[0]}{more}; a "
            "checkpoint carries every model key (none is filled from code defaults)"
        )


def checkpoint_model_config(
    config_yaml: str, path, overrides: Sequence[str] = (), config_file: str = CONFIG_FILE
) -> ModelConfig:
    """The validated ``ModelConfig`` of a checkpoint's ``config.yaml`` (``config_file``: the
    file it came from, named in errors) with inference-only ``overrides`` (keys under
    :data:`INFERENCE_SETTINGS`) applied."""
    from omegaconf import OmegaConf

    saved = OmegaConf.create(config_yaml)
    if "model" not in saved:
        raise CheckpointError(f"checkpoint {path}: config.yaml has no model section")
    for item in overrides:
        key = item.split("=", 1)[0].strip()
        if key in RENAMED_KEYS:
            raise ConfigError(
                f"checkpoint override {item!r}: {key} was renamed {RENAMED_KEYS[key]}"
            )
        if "=" not in item or not key.startswith(INFERENCE_SETTINGS):
            raise ConfigError(
                f"checkpoint override {item!r} must be key=value with a key under "
                f"{', '.join(INFERENCE_SETTINGS)} (settings no weight depends on)"
            )
    _check_keys(OmegaConf.to_container(saved.model), path, config_file)
    schema = OmegaConf.structured(ModelConfig)
    merged = OmegaConf.merge(schema, saved.model, OmegaConf.from_dotlist(list(overrides)))
    return OmegaConf.to_object(merged)


def load_policy(
    path,
    device: torch.device | str = "cpu",
    overrides: Sequence[str] = (),
    expected: type[NavigationPolicy] | None = None,
) -> NavigationPolicy:
    """The agent of checkpoint folder ``path`` (``<run>/checkpoints/best``, or a pretrained
    folder of ``save_pretrained``), verified, in eval mode on ``device``: the class its
    ``model.agent`` names (``expected``: refuse any other), PEFT layers re-applied before the
    weights (``model.safetensors``, the EMA averages when training used EMA) are loaded.
    ``overrides``
    (``"navigator.confirmation.ticks=3"``) change settings that no weight depends on."""
    loaded = read_checkpoint(path)
    config = checkpoint_model_config(loaded.config_yaml, path, overrides, loaded.config_file)
    cls = (
        policy_class(config.agent)
        if expected is None
        else require_agent(config.agent, expected, path)
    )
    policy = cls(config)
    apply_peft(policy, config.peft)
    load_model_state(policy, loaded.model, str(path))
    policy.attach_checkpoint(loaded)  # the perception's ONNX export, with engine=onnxruntime
    return policy.to(device).eval()
