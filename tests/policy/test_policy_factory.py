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
