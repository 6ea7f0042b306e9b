"""The GPU recipes train the VLA-GR agent: each composes to the dual-system agent, built with
the goal head and instruction reader of the recipe's own sizes, through staged pipelines whose
every stage's config is valid (tests/training/test_gpu_recipe_ranks.py runs the stages)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

import vla_gr.configs
from vla_gr.configs import load_config
from vla_gr.policy import VLAGRPolicy, make_policy
from vla_gr.training.pipeline import stage_config

CONFIG_DIR = Path(vla_gr.configs.__file__).parent
GPU_RECIPES = ("config_rtx4060", "config_server")


def _written(name: str, dotted: str):
    """The value of ``dotted`` as the recipe file writes it, or the recipe it names first."""
    tree = yaml.safe_load((CONFIG_DIR / f"{name}.yaml").read_text())
    value = tree
    for part in dotted.split("."):
        if not isinstance(value, dict) or part not in value:
            parents = [p for p in tree["defaults"] if p not in ("base_config", "_self_")]
            return _written(parents[0], dotted) if parents else None
        value = value[part]
    return value


@pytest.mark.parametrize("name", GPU_RECIPES)
def test_a_gpu_recipe_builds_the_dual_system_agent_at_its_own_sizes(name):
    # the reader stage enables the reader; enabling it here builds it as that stage does
    _, cfg = load_config(name, ["model.instruction_reader.enabled=true"])
    policy = make_policy(cfg.model)
    assert type(policy) is VLAGRPolicy
    head, channels = policy.goal_head, _written(name, "model.goal_head.channels")
    assert [stage.conv2.out_channels for stage in head.down] == channels
    assert head.stem.conv2.out_channels == _written(name, "model.goal_head.stem_channels")
    assert head.stem.film.in_features == _written(name, "model.goal_head.text_dim")
    hidden = _written(name, "model.instruction_reader.hidden")
    tagger = policy.instruction_reader.tagger
    assert tagger.project[0].out_features == tagger.gru.hidden_size == hidden
    # what the GPU buys over config_cpu: more pixels, wider parts, more expert houses
    _, cpu = load_config("config_cpu")
    assert cfg.env.image_size >= 128 > cpu.env.image_size
    assert all(c >= d for c, d in zip(channels, cpu.model.goal_head.channels))
    assert len(channels) > len(cpu.model.goal_head.channels)  # one more stage, the widest
    assert hidden > cpu.model.instruction_reader.hidden
    assert cfg.collect.num_episodes >= 5 * cpu.collect.num_episodes
    assert cfg.training.device == "cuda" and cfg.training.amp != "none"


@pytest.mark.parametrize("name", GPU_RECIPES)
def test_every_stage_of_a_gpu_recipe_trains_the_dual_system(name):
    resolved, cfg = load_config(name)
    kinds = [stage.kind for stage in cfg.pipeline.stages]
    assert kinds == [
        "collect", "train", "rollout", "dagger", "train", "room_type", "object_category",
        "rollout", "s1_data", "s1", "instruction_reader", "request_intent", "export",
    ]  # fmt: skip
    for stage in cfg.pipeline.stages:
        _, stage_cfg = stage_config(resolved, stage)  # every stage's config is valid
        assert stage_cfg.model.agent == "dual_system", stage.name
        if stage.kind == "rollout":  # train episodes apart from the expert's
            first = stage_cfg.eval.first_episode
            assert stage_cfg.eval.split == "train" and first >= cfg.collect.num_episodes


def test_the_precision_and_distribution_of_each_gpu_recipe():
    _, rtx = load_config("config_rtx4060")
    assert (rtx.training.amp, rtx.training.gradient_checkpointing) == ("fp16", True)
    assert rtx.training.grad_accum > 1
    _, server = load_config("config_server")
    assert (server.training.amp, server.training.compile) == ("bf16", True)
    assert server.training.ddp_backend == "nccl" and server.env.image_size > rtx.env.image_size
