"""The factory: one class per agent, and self-contained checkpoints (no model setting is
filled from code defaults; a missing, unknown or renamed key fails in one line naming it)."""

from __future__ import annotations

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from vla_gr.checkpoint import CheckpointError, read_checkpoint, save_checkpoint
from vla_gr.policy import EndToEndPolicy, VLAGRPolicy, factory, load_policy

TINY = Path(__file__).parent / "data" / "end_to_end_tiny"


def _rewritten(tmp_path: Path, edit) -> Path:
    """The tiny checkpoint written again with ``edit(config)`` applied to its config."""
    loaded = read_checkpoint(TINY)
    config = OmegaConf.create(loaded.config_yaml)
    edit(config)
    return save_checkpoint(
        tmp_path, 1, loaded.model, loaded.state, OmegaConf.to_yaml(config), links=()
    )


def test_load_policy_builds_the_class_the_checkpoint_names():
    policy = load_policy(TINY)
    assert type(policy) is EndToEndPolicy and not policy.training
    assert type(EndToEndPolicy.from_pretrained(TINY)) is EndToEndPolicy
    with pytest.raises(CheckpointError, match=r"holds model.agent=end_to_end.*not a VLAGRPolicy"):
        VLAGRPolicy.from_pretrained(TINY)


def test_a_checkpoint_without_a_model_key_fails_naming_it(tmp_path):
    path = _rewritten(tmp_path, lambda c: c.model.head.pop("num_inference_steps"))
    with pytest.raises(CheckpointError) as err:
        load_policy(path)
    message = str(err.value)
    assert "lacks model.head.num_inference_steps" in message and "\n" not in message


def test_an_unknown_model_key_fails_naming_it(tmp_path):
    def add(config):
        config.model.head.warp_factor = 9

    with pytest.raises(CheckpointError, match=r"model\.head\.warp_factor.*does not know"):
        load_policy(_rewritten(tmp_path, add))


def test_a_checkpoint_with_an_old_key_fails_naming_the_new_one(tmp_path):
    def old_name(config):
        config.model.navigator.confirm_ticks = config.model.navigator.confirmation.pop("ticks")

    with pytest.raises(CheckpointError) as err:
        load_policy(_rewritten(tmp_path / "renamed", old_name))
    message = str(err.value)
    assert "\n" not in message
    assert "model.navigator.confirm_ticks was renamed model.navigator.confirmation.ticks" in message
    assert "--rename-keys" in message

    def seed_block(config):
        config.model.dual_system = {"visual_dim": 512}

    with pytest.raises(CheckpointError, match=r"model\.dual_system\.visual_dim was removed"):
        load_policy(_rewritten(tmp_path / "removed", seed_block))


@pytest.mark.parametrize(
    "override, new",
    [
        ("navigator.confirm_ticks=3", "navigator.confirmation.ticks"),
        ("navigator.local_planner=true", "navigator.local_planner.enabled"),
        ("navigator.pursuit_lookahead=0.6", "pursuit.lookahead"),
        ("dual_system.planning_frequency_hz=5", "schedule.planning_frequency_hz"),
    ],
)
def test_an_override_with_an_old_key_fails_naming_the_new_one(override, new):
    from vla_gr.configs import ConfigError

    with pytest.raises(ConfigError, match=rf"{override.split('=')[0]} was renamed {new}$"):
        load_policy(TINY, overrides=[override])


def test_every_renamed_key_names_a_key_of_this_version():
    from vla_gr.configs.model_schema import ModelConfig

    schema = factory._leaf_keys(OmegaConf.to_container(OmegaConf.structured(ModelConfig)))
    assert set(factory.RENAMED_KEYS.values()) <= schema
    assert not (set(factory.RENAMED_KEYS) | set(factory.REMOVED_KEYS)) & schema
    assert all(new.startswith(factory.INFERENCE_SETTINGS) for new in (
        factory.RENAMED_KEYS[f"navigator.{k}"] for k in ("confirm_ticks", "local_planner")
    ))  # fmt: skip


def test_a_renamed_key_names_its_new_name(tmp_path, monkeypatch):
    def rename(config):
        config.model.head.denoising_steps = config.model.head.pop("num_inference_steps")

    monkeypatch.setattr(
        factory, "RENAMED_KEYS", {"head.denoising_steps": "head.num_inference_steps"}
    )
    with pytest.raises(CheckpointError, match=r"head\.denoising_steps was renamed.*"
                       r"head\.num_inference_steps"):  # fmt: skip
        load_policy(_rewritten(tmp_path, rename))


def test_an_unknown_agent_names_the_valid_ones():
    from vla_gr.configs import ConfigError

    with pytest.raises(ConfigError, match="valid agents: dual_system, end_to_end"):
        factory.policy_class("s2")
