"""Eval variants: named agents made of a registered agent, a checkpoint and overrides
(resolution, overrides reaching the policy, the true mask on a checkpoint, compare rows)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace as Namespace

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from vla_gr import __version__
from vla_gr.agent.followers import LearnedFollower, PurePursuit
from vla_gr.agent.perception.percept import TrueCategoryGate, TrueMaskPerception
from vla_gr.checkpoint import save_checkpoint
from vla_gr.cli import main as cli_main
from vla_gr.configs import load_config
from vla_gr.configs.schema import VariantConfig
from vla_gr.evaluate import compare, expand_aliases
from vla_gr.evaluation.agents import (
    AgentError,
    check_agent,
    make_agent,
    resolve_agent,
    true_category_agent,
    true_mask_agent,
)
from vla_gr.policy import VLAGRPolicy, make_policy

FAST = ["eval.progress=false", "eval.video_successes=0", "eval.video_per_cause=0"]
TINY = [
    "model.goal_head.text_encoder=hashed",
    "model.encoders.text_encoder=hashed",
    "model.s1.channels=[8,8]",
]


def write_checkpoint(folder: Path, *overrides: str) -> str:
    """A tiny untrained agent (config_debug's env: 32 px) saved as a checkpoint folder."""
    resolved, cfg = load_config("config_debug", [*TINY, *overrides])
    torch.manual_seed(0)
    tensors = {k: v.contiguous() for k, v in make_policy(cfg.model).state_dict().items()}
    state = {"step": 0, "vla_gr_version": __version__}
    path = save_checkpoint(folder, 0, tensors, state, OmegaConf.to_yaml(resolved), links=())
    return str(path)


@pytest.fixture(scope="module")
def dual(tmp_path_factory) -> str:
    """A dual system with a learned S1 and S2 every 4 control steps (config_debug: 10)."""
    tmp = tmp_path_factory.mktemp("dual")
    rate = "model.schedule.planning_frequency_hz=5"
    return write_checkpoint(tmp, "model.agent=dual_system", "model.s1.kind=learned", rate)


def eval_cfg(*overrides: str, **variants: VariantConfig):
    cfg = load_config("config_debug", expand_aliases([*FAST, *overrides]))[1]
    return dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, variants=variants))


def test_a_name_resolves_to_a_registered_agent_or_a_variant():
    cfg = eval_cfg(
        "checkpoint=/runs/a", mine=VariantConfig(), other=VariantConfig(checkpoint="/runs/b")
    )
    assert resolve_agent("random", cfg) == ("random", cfg)
    base, sub = resolve_agent("mine", cfg)
    assert base == "checkpoint" and sub.eval.checkpoint == "/runs/a"  # inherits eval's
    assert resolve_agent("other", cfg)[1].eval.checkpoint == "/runs/b"
    with pytest.raises(
        AgentError, match=r"valid agents: checkpoint, .*random.*; variants: mine, other"
    ):
        resolve_agent("nope", cfg)
    with pytest.raises(AgentError, match="eval.variants.random has the name of a registered"):
        resolve_agent("mine", eval_cfg(random=VariantConfig()))
    with pytest.raises(ValueError, match="agent='expert' is not valid"):
        VariantConfig(agent="expert")


def test_a_variants_overrides_reach_its_policy(dual):
    cfg = eval_cfg(
        f"checkpoint={dual}",
        plain=VariantConfig(),
        pursuit=VariantConfig(model_overrides=["s1.kind=pure_pursuit"]),
        blind=VariantConfig(model_overrides=["s1.use_s2=false", "s1.stop_threshold=0.9"]),
    )
    plain = make_agent("plain", cfg, None).policy
    assert isinstance(plain.dual_system.follower, LearnedFollower)
    assert plain.config.s1.use_s2 and plain.dual_system.plan_every == 4
    assert isinstance(make_agent("pursuit", cfg, None).policy.dual_system.follower, PurePursuit)
    blind = make_agent("blind", cfg, None).policy.dual_system.follower
    assert not blind.config.use_s2 and blind.config.stop_threshold == 0.9
    # overrides that do not apply are refused up front, naming the variant
    bad = {"bad": VariantConfig(model_overrides=["navigator.nope=1"])}
    with pytest.raises(AgentError, match="agent bad: model_overrides=.*nope"):
        check_agent("bad", eval_cfg(f"checkpoint={dual}", **bad))
    weights = {"w": VariantConfig(model_overrides=["s1.dim=8"])}
    with pytest.raises(AgentError, match="agent w: .*settings no weight depends on"):
        check_agent("w", eval_cfg(f"checkpoint={dual}", **weights))


def test_true_mask_on_a_checkpoint_uses_its_dual_system(dual, tmp_path):
    cfg = eval_cfg(
        f"checkpoint={dual}",
        ceiling=VariantConfig(
            agent="true_mask", model_overrides=["navigator.confirmation.ticks=5"]
        ),
        ceiling_pp=VariantConfig(agent="true_mask", model_overrides=["s1.kind=pure_pursuit"]),
    )
    ceiling = make_agent("ceiling", cfg, None).policy
    system = ceiling.dual_system
    assert isinstance(ceiling.perception, TrueMaskPerception)  # the wiring is the checkpoint's
    assert isinstance(system.follower, LearnedFollower) and system.plan_every == 4
    assert system.navigator.config.confirmation.ticks == 5
    loaded = VLAGRPolicy.from_pretrained(dual).s1.state_dict()
    for key, value in system.follower.policy.state_dict().items():
        assert torch.equal(value, loaded[key])  # the checkpoint's S1
    pursuit = make_agent("ceiling_pp", cfg, None).policy.dual_system.follower
    assert isinstance(pursuit, PurePursuit)
    # without a checkpoint: cfg.model's dual system, as before
    plain = true_mask_agent(eval_cfg(), None).system
    assert isinstance(plain.follower, PurePursuit) and plain.plan_every == 10
    assert isinstance(plain.perception, TrueMaskPerception)
    e2e = write_checkpoint(tmp_path, "model.agent=end_to_end")
    with pytest.raises(AgentError, match="model.agent=end_to_end.*agent=true_mask needs"):
        check_agent("true_mask", eval_cfg(f"checkpoint={e2e}"))


def test_true_category_runs_the_checkpoints_checks_and_true_mask_needs_none(tmp_path):
    room = write_checkpoint(
        tmp_path, "model.agent=dual_system", "model.room_type.enabled=true",
        "model.navigator.goal_checks.room_reject_threshold=0.2",
        "model.object_category.enabled=true",
    )  # fmt: skip
    world = Namespace(unwrapped=Namespace())
    policy = true_category_agent(eval_cfg(f"checkpoint={room}"), world).policy
    perception = policy.perception
    assert policy.room_type is not None and perception.room_type is policy.room_type
    assert perception.object_category is policy.object_category
    assert isinstance(perception.gate, TrueCategoryGate)
    # the ceiling knows the goal's pixels: nothing to check
    ceiling = make_agent("true_mask", eval_cfg(f"checkpoint={room}"), world).policy
    assert isinstance(ceiling.perception, TrueMaskPerception)


def test_true_category_keeps_the_goal_heads_pixels_on_the_goal_category_only(dual, tmp_path):
    chair, other_chair, table = (Namespace(instance_id=i, category=c) for i, c in
                                 ((3, "chair"), (5, "chair"), (7, "table")))  # fmt: skip
    world = Namespace(house=Namespace(objects=[chair, other_chair, table]), goal=chair)
    agent = true_category_agent(eval_cfg(f"checkpoint={dual}"), Namespace(unwrapped=world))
    rng = np.random.default_rng(0)
    semantic = rng.choice([0, 3, 5, 7], size=(32, 32))  # (H, W) instance ids
    obs = {
        "rgb": rng.integers(0, 255, (32, 32, 3), dtype=np.uint8),
        "depth": rng.uniform(0.5, 5.0, (32, 32, 1)).astype(np.float32),
        "pose": np.zeros(3, np.float32),
        "instruction": "find the chair",
        "semantic": semantic,
    }
    raw = agent.policy.learned_perception().perceive(obs)
    gated = agent.policy.perception.perceive(obs)
    chairs = np.isin(semantic, [3, 5])  # the goal and its same-category distractor
    assert gated.visible == raw.visible and raw.likelihood[~chairs].max() > 0
    assert np.array_equal(gated.likelihood[chairs], raw.likelihood[chairs])
    assert not gated.likelihood[~chairs].any()
    assert agent.parameters()["total"] == sum(p.numel() for p in agent.policy.parameters())
    with pytest.raises(ValueError, match="agent=true_category needs the env's semantic"):
        agent.policy.perception.perceive({k: v for k, v in obs.items() if k != "semantic"})
    with pytest.raises(AgentError, match="give checkpoint="):
        true_category_agent(eval_cfg(), None)
    e2e = write_checkpoint(tmp_path, "model.agent=end_to_end")
    with pytest.raises(AgentError, match="model.agent=end_to_end.*agent=true_category needs"):
        check_agent("true_category", eval_cfg(f"checkpoint={e2e}"))


def test_true_category_reads_the_request_as_the_checkpoint_does(dual):
    sofa = Namespace(instance_id=3, category="sofa")
    world = Namespace(house=Namespace(objects=[sofa]), goal=sofa)
    agent = true_category_agent(eval_cfg(f"checkpoint={dual}"), Namespace(unwrapped=world))
    seen = []
    head = agent.policy.goal_head
    likelihood = head.likelihood
    head.likelihood = lambda rgb, depth, text, network=None: (
        seen.extend(text) or likelihood(rgb, depth, text, network)
    )
    obs = {
        "rgb": np.zeros((32, 32, 3), np.uint8),
        "depth": np.full((32, 32, 1), 2.0, np.float32),
        "pose": np.zeros(3, np.float32),
        "instruction": "find the sofa next to the tv",
        "semantic": np.full((32, 32), 3),
    }
    agent.reset(0)
    agent.act(obs)
    assert seen == ["find the sofa next to the tv"]  # no reader: the template words as said
    assert agent.policy.reading.fields() == {"category": "sofa", "color": None, "room": None,
                                             "anchor": "tv_monitor"}  # fmt: skip
    agent.reset(1)
    assert agent.policy.reading is None


def test_a_missing_variant_checkpoint_stops_before_any_episode(tmp_path, capsys):
    out = tmp_path / "out"
    made_by = "vla-gr train --config-name recipe_ablations"
    variant = f"+eval.variants={{gone:{{checkpoint:{tmp_path / 'gone'},made_by:'{made_by}'}}}}"
    argv = ["eval", "--config-name", "config_debug", f"output_dir={out}", *FAST, variant]
    assert cli_main([*argv, "agents=[random,gone]"]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err == f"vla-gr eval: error: agent gone: checkpoint {tmp_path / 'gone'} does not "
        f"exist; make it with: {made_by}"
    )
    assert cli_main([*argv, "agent=nope"]) == 2
    assert (
        "valid agents: checkpoint," in (err := capsys.readouterr().err) and "variants: gone" in err
    )
    assert not out.exists()


def test_compare_writes_a_row_per_variant_with_its_checkpoint_and_overrides(dual, tmp_path):
    pursuit = ["s1.kind=pure_pursuit"]
    cfg = eval_cfg(
        f"checkpoint={dual}",
        f"output_dir={tmp_path}",
        "agents=[learned,pursuit]",
        "num_episodes=2",
        "workers=2",
        "env.max_episode_steps=6",
        learned=VariantConfig(),
        pursuit=VariantConfig(model_overrides=pursuit),
    )
    compare(cfg)
    rows = json.loads((tmp_path / "compare.json").read_text())
    assert list(rows) == ["learned", "pursuit"]
    for name, overrides in (("learned", []), ("pursuit", pursuit)):
        assert rows[name]["agent"] == "checkpoint" and rows[name]["checkpoint"] == dual
        assert rows[name]["model_overrides"] == overrides and rows[name]["episodes"] == 2
        metrics = json.loads((tmp_path / name / "metrics.json").read_text())
        assert metrics["agent"] == name and metrics["base_agent"] == "checkpoint"
        assert metrics["model_overrides"] == overrides
    actions = {
        name: [json.loads(x)["actions"] for x in (tmp_path / name / "episodes.jsonl").open()]
        for name in rows
    }
    assert actions["learned"] != actions["pursuit"]  # the workers built each variant
    md = (tmp_path / "compare.md").read_text()
    assert "## Agents" in md and "| pursuit " in md and "s1.kind=pure_pursuit" in md


def test_the_ablations_recipe_names_an_agent_for_every_row(tmp_path):
    missing = tmp_path / "none"
    cfg = load_config("compare_ablations", [f"eval.variants.s1_ddim.checkpoint={missing}"])[1]
    bases = {name: resolve_agent(name, cfg)[0] for name in cfg.eval.agents}
    registered = ("true_mask", "true_category", "random")
    assert all(bases[name] == name for name in registered)
    assert {bases[n] for n in cfg.eval.agents if n not in registered} == {"checkpoint"}
    with pytest.raises(AgentError, match=r"agent s1_ddim: .* make it with: vla-gr train --config"):
        check_agent("s1_ddim", cfg)
