"""Recipes compose, set only what differs from the defaults, and defaults cannot drift."""

from __future__ import annotations

import dataclasses
import inspect
import re
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

import vla_gr.configs
from vla_gr.configs import load_config
from vla_gr.configs.model_schema import FOLLOWS, ModelConfig
from vla_gr.configs.schema import EnvConfig, VLAGRConfig
from vla_gr.core.diffusion_policy import DiffusionPolicy, HeadConfig, L1RegressionHead
from vla_gr.core.dual_system import DualSystemArchitecture, DualSystemConfig
from vla_gr.core.encoders import (
    EncodersConfig,
    HashedTextEncoder,
    PoseEncoder,
    RGBDEncoder,
    build_text_encoder,
)
from vla_gr.core.gr_field import GRField, GRFieldConfig
from vla_gr.geometry import robot_spec

CONFIG_DIR = Path(vla_gr.configs.__file__).parent
RECIPES = sorted(p.stem for p in CONFIG_DIR.glob("config_*.yaml"))


def _leaves(tree: dict, prefix: str = ""):
    for key, value in tree.items():
        if key == "defaults":
            continue
        if isinstance(value, dict):
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


@pytest.mark.parametrize("name", RECIPES)
def test_recipe_composes_and_components_follow_the_layout(name):
    _, cfg = load_config(name)
    m = cfg.model
    assert m.image_size == cfg.env.image_size
    assert (m.head.action_dim, m.head.horizon) == (m.action_dim, m.horizon)
    assert m.head.context_dim == m.encoders.dim
    assert m.schedule.planning_frequency_hz <= m.schedule.control_frequency_hz
    head = DiffusionPolicy(config=m.head)
    assert head.context_dim == m.encoders.dim and head.default_sampler is not None


@pytest.mark.parametrize("name", RECIPES)
def test_recipe_sets_only_non_defaults_each_with_a_reason(name):
    """Each key differs from what the recipe inherits: the schema, or the recipe it names."""
    text = (CONFIG_DIR / f"{name}.yaml").read_text()
    tree = yaml.safe_load(text)
    parents = [p for p in tree.get("defaults", []) if p not in ("base_config", "_self_")]
    if parents:
        defaults = OmegaConf.to_container(load_config(parents[0])[0])
    else:
        defaults = OmegaConf.to_container(OmegaConf.structured(VLAGRConfig))
    for key, value in _leaves(tree):
        default = defaults
        for part in key.split("."):
            default = default[part]
        assert value != default, f"{name}: {key}={value!r} repeats what it inherits"
        leaf = key.rsplit(".", 1)[-1]
        line = next(ln for ln in text.splitlines() if re.match(rf"\s*{leaf}:", ln))
        assert "#" in line, f"{name}: {key} has no reason beside it"


def test_component_fields_follow_the_model_and_contradictions_fail():
    _, cfg = load_config("config_debug", ["model.horizon=6", "model.encoders.dim=48"])
    assert cfg.model.head.horizon == 6 and cfg.model.head.context_dim == 48
    direct = ModelConfig(horizon=12, n_action_steps=4)
    assert direct.head.horizon == 12 and direct.head.context_dim == direct.encoders.dim
    with pytest.raises(ValueError, match=r"model\.head\.horizon=5 contradicts model\.horizon"):
        load_config("config_debug", ["model.head.horizon=5"])
    assert set(FOLLOWS) >= {("head", "action_dim"), ("head", "horizon"), ("head", "context_dim")}


def test_the_agents_schedule_is_its_own_section_apart_from_the_seeds_block():
    _, cfg = load_config("config_cpu")
    schedule = cfg.model.schedule
    assert schedule.control_frequency_hz == cfg.env.control_hz  # S1 at the world's rate
    assert schedule.planning_frequency_hz == 3.3
    # the seed's latent DualSystemArchitecture, which no agent runs, is no model section
    assert "dual_system" not in {f.name for f in dataclasses.fields(ModelConfig)}
    with pytest.raises(ValueError, match=r"model\.schedule\.planning_frequency_hz"):
        load_config("config_debug", ["model.schedule.planning_frequency_hz=0"])
    with pytest.raises(ValueError, match=r"DualSystemConfig\.planning_frequency_hz"):
        DualSystemConfig(planning_frequency_hz=0.0)


def test_agent_sensor_settings_follow_the_world():
    _, cfg = load_config("config_debug", ["env.max_depth=5.0", "env.image_size=48"])
    assert cfg.model.image_size == 48
    assert cfg.model.encoders.max_depth == 5.0 and cfg.model.gr_field.max_depth == 5.0


def _signature_defaults(fn) -> dict:
    return {
        k: p.default
        for k, p in inspect.signature(fn).parameters.items()
        if p.default is not inspect.Parameter.empty
    }


def test_keyword_constructors_default_to_the_configs():
    enc = EncodersConfig()
    rgbd = _signature_defaults(RGBDEncoder.__init__)
    assert list(rgbd["channels"]) == enc.vision_channels
    assert (rgbd["dim"], rgbd["pool"], rgbd["num_tokens"], rgbd["max_depth"]) == (
        enc.dim,
        enc.vision_pool,
        enc.vision_tokens,
        enc.max_depth,
    )
    assert rgbd["gradient_checkpointing"] == enc.gradient_checkpointing
    assert _signature_defaults(HashedTextEncoder.__init__)["buckets"] == enc.text_buckets
    assert _signature_defaults(build_text_encoder)["buckets"] == enc.text_buckets
    assert _signature_defaults(PoseEncoder.__init__)["hidden"] == enc.pose_hidden
    head = HeadConfig()
    for key, value in _signature_defaults(L1RegressionHead.__init__).items():
        if key != "context_dim":
            assert value == getattr(head, key), key
    # Components built from their config with no arguments carry exactly the defaults.
    assert DiffusionPolicy().config == head
    assert DualSystemArchitecture().config == DualSystemConfig()
    assert GRField().config == GRFieldConfig()


def test_seed_positional_order_is_the_config_field_order():
    head_fields = [f.name for f in dataclasses.fields(HeadConfig)][:5]
    assert head_fields == [
        "action_dim",
        "hidden_dim",
        "context_dim",
        "num_diffusion_steps",
        "prediction_type",
    ]
    policy = DiffusionPolicy(7, 64, 32, 50, "epsilon")
    assert (policy.action_dim, policy.hidden_dim, policy.context_dim) == (7, 64, 32)
    assert (policy.num_diffusion_steps, policy.prediction_type) == (50, "epsilon")
    dual = DualSystemArchitecture(16, 12, 32, 32, 2.0, 10.0, s2_num_heads=4)
    assert (dual.visual_dim, dual.vlm_dim, dual.goal_dim, dual.plan_every) == (16, 12, 32, 5)
    with pytest.raises(ValueError, match="not both"):
        DiffusionPolicy(7, config=HeadConfig())


def test_sensor_defaults_come_from_the_robot_spec():
    assert EnvConfig().max_depth == robot_spec.MAX_DEPTH
    assert EncodersConfig().max_depth == robot_spec.MAX_DEPTH
    gr = GRFieldConfig()
    assert (gr.hfov_deg, gr.camera_height, gr.robot_radius) == (
        robot_spec.HFOV_DEG,
        robot_spec.CAMERA_HEIGHT,
        robot_spec.ROBOT_RADIUS,
    )
    assert (gr.min_depth, gr.max_depth) == (robot_spec.MIN_DEPTH, robot_spec.MAX_DEPTH)


def test_one_option_list_per_choice():
    from vla_gr.core.diffusion_policy import config as head_config
    from vla_gr.core.diffusion_policy import flow_matching, noise_targets

    assert flow_matching.FLOW_SAMPLERS is head_config.FLOW_SAMPLERS
    assert noise_targets.PREDICTION_TYPES is head_config.PREDICTION_TYPES
    assert head_config.SAMPLERS["flow_matching"] == head_config.FLOW_SAMPLERS
    assert head_config.SAMPLERS["l1"] == ()
    with pytest.raises(ValueError, match=r"model\.head\.sampler.*euler"):
        HeadConfig(objective="flow_matching", sampler="ddim")
    with pytest.raises(ValueError, match=r"model\.head\.sampler"):
        HeadConfig(objective="l1", sampler="euler")
