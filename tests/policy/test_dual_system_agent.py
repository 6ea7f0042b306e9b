"""The dual-system agent's goal head: what it builds, its loss, config checks, and training
(2 steps, resume, ``from_pretrained``) through the generic trainer."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from tests.helpers import train_overrides
from vla_gr.agent.followers import LearnedFollower
from vla_gr.agent.followers.s1_inputs import PlanMemory
from vla_gr.agent.navigator import NavPlan
from vla_gr.agent.navigator.navigator import MODES
from vla_gr.agent.perception import goal_head_loss
from vla_gr.checkpoint import CheckpointError
from vla_gr.configs import ConfigError, load_config
from vla_gr.data.dataset import EpisodeWindowDataset
from vla_gr.policy import EndToEndPolicy, VLAGRPolicy, make_fake_batch, make_policy
from vla_gr.policy.factory import POLICY_CLASSES
from vla_gr.train import train
from vla_gr.training.data import make_loader
from vla_gr.training.logger import read_metrics
from vla_gr.training.step import validate

DUAL = ["model.agent=dual_system"]


def _model(*overrides: str) -> VLAGRPolicy:
    _, cfg = load_config("config_debug", [*DUAL, "model.goal_head.text_encoder=hashed", *overrides])
    torch.manual_seed(0)
    return VLAGRPolicy(cfg.model)


def test_builds_only_the_goal_head_and_its_loss_is_the_last_frames():
    model = _model("model.grounding.pos_weight=2.0", "model.grounding.visible_weight=0.25")
    assert type(model) is VLAGRPolicy
    for end_to_end in ("vision", "text", "pose", "fusion", "head"):
        assert not hasattr(model, end_to_end), end_to_end
    batch = make_fake_batch(model.config, batch_size=3, seed=1)
    out = model(batch)
    direct = model.goal_head(batch["rgb"][:, -1], batch["depth"][:, -1], batch["instruction"])
    expected = goal_head_loss(
        direct["pixel_logits"],
        direct["visible_logits"],
        batch["goal_mask"][:, -1, 0],
        pos_weight=2.0,
        visible_weight=0.25,
    )
    for key in ("loss", "pixel_bce", "dice", "visible_bce"):
        torch.testing.assert_close(out[key], expected[key])
    assert out["loss"].requires_grad and not out["dice"].requires_grad
    # the first observation frame does not enter the loss
    changed = dict(batch, rgb=batch["rgb"].clone(), goal_mask=batch["goal_mask"].clone())
    changed["rgb"][:, 0] = 0.0
    changed["goal_mask"][:, 0] = True
    torch.testing.assert_close(model(changed)["loss"], out["loss"])


def test_the_category_output_learns_goal_or_distractors_and_gates_the_metrics():
    model = _model("model.goal_head.category_head=true", "model.grounding.category_weight=0.5")
    batch = make_fake_batch(model.config, batch_size=3, seed=2)
    goal, others = batch["goal_mask"][:, -1, 0], batch["distractor_mask"][:, -1, 0]
    assert others.any() and not (goal & others).any()
    out = model(batch)
    direct = model.goal_head(batch["rgb"][:, -1], batch["depth"][:, -1], batch["instruction"])
    expected = goal_head_loss(
        direct["pixel_logits"],
        direct["visible_logits"],
        goal,
        category_logits=direct["category_logits"],
        category_target=goal | others,  # every instance of the category: a distractor is 1
        category_weight=0.5,
    )
    for key in ("loss", "category_bce", "category_dice"):
        torch.testing.assert_close(out[key], expected[key])
    # the held-out metrics score the gated probability S2 uses, not the raw instance output
    outputs = model.goal_outputs(batch)
    gated = torch.sigmoid(direct["pixel_logits"]) * torch.sigmoid(direct["category_logits"])
    counts = model.goal_confusion(outputs)
    raw = torch.sigmoid(direct["pixel_logits"])  # (B, H, W)
    assert int((raw >= 0.5).sum()) != int((gated >= 0.5).sum())  # the check can tell them apart
    assert counts["tp"] + counts["fp"] == int((gated >= 0.5).sum())
    without = {k: v for k, v in batch.items() if k != "distractor_mask"}
    with pytest.raises(ValueError, match="distractor_mask"):
        model(without)


def _obs(pose=(0.0, 0.0, 0.0)) -> dict:
    return {
        "rgb": np.zeros((32, 32, 3), np.uint8),
        "depth": np.full((32, 32, 1), 3.0, np.float32),
        "pose": np.asarray(pose, np.float32),
        "instruction": "find the chair",
    }


def test_s2_runs_every_plan_every_steps_and_s1_every_step():
    # 10 Hz control, 10/3 Hz planning -> an S2 tick every 3 control steps
    model = _model(
        "model.schedule.control_frequency_hz=10", "model.schedule.planning_frequency_hz=3.3"
    )
    system = model.dual_system
    assert system.plan_every == 3
    ticks = []
    perceive = system.perception.perceive
    system.perception.perceive = lambda obs: ticks.append(len(ticks)) or perceive(obs)
    model.reset()
    s2_steps = []
    for t in range(8):
        action = model.select_action(_obs())
        assert action.shape == (3,) and np.abs(action).max() <= 1.0
        timings = model.last_timings
        assert "s1" in timings
        if "s2" in timings:
            s2_steps.append(t)
            # the tick's two parts: perception then the navigator, inside the tick's time
            parts = timings["s2_perception"] + timings["s2_navigator"]
            assert 0 < parts <= timings["s2"]
        else:
            assert "s2_perception" not in timings and "s2_navigator" not in timings
    assert s2_steps == [0, 3, 6] and len(ticks) == 3
    model.reset()  # a new episode plans at once
    model.select_action(_obs())
    assert len(ticks) == 4 and "s2" in model.last_timings
    assert model.predict_action_chunk(_obs()).shape == (1, 1, 3)
    assert isinstance(model.predict_action_chunk(_obs()), torch.Tensor)


def test_s1_acts_on_the_latest_plan_between_ticks():
    model = _model(
        "model.schedule.control_frequency_hz=10", "model.schedule.planning_frequency_hz=5"
    )
    system = model.dual_system  # plan_every 2
    plans = iter(
        [
            NavPlan(np.zeros((0, 2)), "look_around", 0.0, False, command=(0.0, 1.0)),
            NavPlan(np.zeros((0, 2)), "stop", 1.0, True),
        ]
    )
    system.navigator.plan = lambda obs, likelihood, *checks: next(plans)
    model.reset()
    first = [model.select_action(_obs()).tolist() for _ in range(2)]
    assert first == [[0.0, 1.0, -1.0]] * 2  # the first plan's turn, held until the next tick
    assert model.select_action(_obs()).tolist() == [0.0, 0.0, 1.0]  # the new plan: STOP
    assert system.max_goal_confidence == 1.0


LEARNED_S1 = [
    "model.s1.kind=learned",
    "model.s1.image_size=16",
    "model.s1.channels=[8,16]",
    "model.s1.dim=32",
    "model.s1.head.hidden_dim=16",
    "model.s1.head.horizon=4",
    "model.s1.head.num_inference_steps=2",
    "model.s1.n_action_steps=1",  # S1 decides every step: it shows what it reads each step
]


def test_learned_s1_reads_the_latest_plan_and_s2_runs_every_plan_every_steps():
    model = _model(
        "model.schedule.control_frequency_hz=10",
        "model.schedule.planning_frequency_hz=3.3",
        *LEARNED_S1,
    )
    system = model.dual_system
    follower = system.follower
    assert isinstance(follower, LearnedFollower) and follower.policy is model.s1
    assert system.plan_every == 3
    likelihood_steps = []
    perceive = system.perception.perceive
    system.perception.perceive = lambda obs: likelihood_steps.append(system.steps) or perceive(obs)
    plans = iter(
        NavPlan(np.array([[1.0 + k, 0.5 * k]]), "explore", 0.1 * k, False) for k in range(4)
    )
    system.navigator.plan = lambda obs, likelihood, *checks: next(plans)
    read = []  # the plan vector S1 read at each call
    act = follower.policy.act

    def reading(rgb, depth, plan, generator=None):
        read.append(plan[0].numpy().copy())
        return act(rgb, depth, plan, generator)

    follower.policy.act = reading
    model.reset()
    memory = PlanMemory(model.config.s1.path_points)  # what S1 should read, rebuilt here
    made = []
    for t in range(10):
        pose = np.array([0.2 * t, 0.05 * t, 0.1 * t])
        previous = system.plan
        action = model.select_action(_obs(pose))
        assert action.shape == (3,) and np.abs(action).max() <= 1.0
        if t % 3 == 0:
            assert system.plan is not previous
            made.append(system.plan)
            memory.set_plan(system.plan, pose, t)
        assert system.plan is made[-1] and follower.memory.plan is system.plan
        assert len(read) == t + 1
        np.testing.assert_allclose(read[-1], memory.vector(pose, t), atol=1e-6)
    assert likelihood_steps == [0, 3, 6, 9]
    ages = [round(float(v[-1]) * 10) for v in read]
    assert ages == [0, 1, 2, 0, 1, 2, 0, 1, 2, 0]
    # confidence, goal distance, goal known, speed cap, modes, age
    confidence = [float(v[-5 - len(MODES)]) for v in read]
    assert confidence == pytest.approx([0.1 * (t // 3) for t in range(10)])


def _batch(*rows: dict) -> dict:
    """A vector env's observation of ``rows`` (one per env)."""
    batch = {k: np.stack([r[k] for r in rows]) for k in rows[0] if k != "instruction"}
    return batch | {"instruction": tuple(r["instruction"] for r in rows)}


def test_a_batch_keeps_one_dual_system_per_env_and_a_done_env_alone_starts_again():
    model = _model()
    said = ["find the chair", "qwzx plorf"]  # env 1's request is not understood
    lone = [model.select_action({**_obs(), "instruction": said[0]}).tolist() for _ in range(3)]
    model.reset()
    batch = _batch(*({**_obs(), "instruction": s} for s in said))
    steps, actions = [], []
    for t in range(6):
        actions.append(model.select_action(batch, done=[t == 3, False]).tolist())  # (2, 3)
        steps.append([system.steps for system in model.dual_systems])
    # env 0's row at step 3 ended its episode: no action, its state alone starts again
    assert steps == [[1, 1], [2, 2], [3, 3], [0, 4], [1, 5], [2, 6]]
    assert [a[0] for a in actions] == lone + [[0.0, 0.0, 0.0]] + lone[:2]
    assert all(a[1] == [0.0, 0.0, 0.0] for a in actions)  # env 1 does not act on its request
    first, second = model.dual_systems
    assert first.declared_outcome is None and first.reading.fields()["category"] == "chair"
    assert second.declared_outcome == "not_understood" and first.perception is model.perception
    assert second.perception is not first.perception
    model.reset()
    assert model.dual_systems == (first,) and first.steps == 0  # env 0's system, restarted


def test_the_number_of_envs_holds_until_reset_and_inputs_are_checked():
    model = _model()
    model.select_action(_batch(_obs(), _obs()))
    with pytest.raises(ValueError, match=r"acts for 2 env\(s\) since its last reset"):
        model.select_action(_obs())
    with pytest.raises(ValueError, match="one flag per env"):
        model.select_action(_batch(_obs(), _obs()), done=[True])
    with pytest.raises(ValueError, match=r"obs\['pose'\] of shape \(1, 3\)"):
        model.select_action(_batch(_obs(), _obs()) | {"pose": np.zeros((1, 3), np.float32)})
    model.reset()
    assert model.select_action(_obs()).shape == (3,)
    with pytest.raises(ValueError, match=r"\(H, W, 3\) for one env or \(B, H, W, 3\)"):
        model.select_action({**_obs(), "rgb": np.zeros((32, 3), np.uint8)})


def test_a_perception_that_reads_one_envs_ground_truth_drives_one_env():
    model = _model()
    model.use_perception(model.learned_perception().gated(lambda obs: np.ones((32, 32), bool)))
    with pytest.raises(ValueError, match="gated perception .* drives one env"):
        model.select_action(_batch(_obs(), _obs()))
    assert model.select_action(_obs()).shape == (3,)  # a failed call fixed no number of envs


def test_the_factory_builds_one_class_per_agent():
    _, cfg = load_config("config_debug")
    model = make_policy(cfg.model)
    assert cfg.model.agent == "end_to_end" and type(model) is EndToEndPolicy
    assert not hasattr(model, "goal_head") and not hasattr(model, "goal_outputs")
    dual = make_policy(_model().config)
    assert type(dual) is VLAGRPolicy and not hasattr(dual, "head")
    assert {"dual_system": VLAGRPolicy, "end_to_end": EndToEndPolicy} == POLICY_CLASSES


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["model.agent=s2"], r"model\.agent"),
        ([*DUAL, "env.image_size=36"], r"model\.image_size=36 must be divisible by 8"),
        ([*DUAL, "model.freeze=[vision]"], r"model\.freeze.*dual_system"),
        (["training.best_metric=goal_iou"], r"goal_iou.*model\.agent=dual_system"),
        ([*DUAL, "training.best_metric=goal_iou", "training.val_ratio=0"], r"val_ratio > 0"),
        ([*DUAL, "model.grounding.threshold=0"], r"model\.grounding\.threshold"),
    ],
)
def test_bad_agent_settings_fail_naming_the_key(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config("config_debug", overrides)


def test_goal_head_max_depth_follows_the_world():
    _, cfg = load_config("config_debug", [*DUAL, "env.max_depth=5.0"])
    assert cfg.model.goal_head.max_depth == 5.0


# --------------------------------------------------------------------------- training

COMMON = {
    "model.agent": "dual_system",
    "training.best_metric": "goal_iou",
    "training.val_batches": 8,  # every held-out window: the metrics do not depend on order
    "training.warmup_steps": 0,
    "training.min_lr_ratio": 1.0,  # constant LR: the schedule cannot depend on `steps`
}


def _run(tmp: Path, **extra) -> dict:
    resolved, cfg = load_config("config_debug", train_overrides(tmp, **COMMON | extra))
    return train(cfg, resolved)


def test_trains_resumes_and_reloads_with_identical_goal_head(tmp_path):
    straight = _run(tmp_path, **{"training.steps": 3, "training.run_name": "straight"})
    _run(tmp_path, **{"training.steps": 2, "training.run_name": "split"})
    split = tmp_path / "runs" / "split"
    rows = read_metrics(split / "metrics.jsonl")
    assert {"train/pixel_bce", "train/dice", "train/visible_bce"} <= set(rows[0])
    logged = next(r for r in rows if "val/goal_iou" in r)
    for key in ("precision", "recall", "iou", "visible_accuracy", "on_distractor"):
        assert 0.0 <= logged[f"val/goal_{key}"] <= 1.0, key
    best = split / "checkpoints" / "best"
    state = json.loads((best / "trainer_state.json").read_text())
    assert state["best_metric"] == "goal_iou"
    assert state["best_score"][0] == pytest.approx(logged["val/goal_iou"])

    # The checkpoint holds the sentence encoder's projection, not the frozen MiniLM.
    saved = load_file(str(best / "model.safetensors"))
    assert "goal_head.text.proj.weight" in saved
    assert not any("backbone" in k or "embeddings" in k for k in saved)

    # Reloaded, it reproduces the logged held-out metrics on the same windows.
    policy = VLAGRPolicy.from_pretrained(best)
    val = EpisodeWindowDataset(
        tmp_path / "syn.zarr", n_obs_steps=2, horizon=8, split="val", val_ratio=0.25
    )
    loader = make_loader(val, 4, None, 0, 0, False)
    loss, metrics = validate(policy, loader, 100, torch.device("cpu"), "none", 0)
    assert loss == pytest.approx(logged["val/loss"], rel=1e-5)
    assert metrics["val/goal_iou"] == pytest.approx(logged["val/goal_iou"], rel=1e-6)

    # Resumed to 3 steps it ends with the same weights as 3 straight steps.
    resume = split / "checkpoints" / "latest"
    assert _run(tmp_path, **{"training.steps": 3, "training.resume": str(resume)})["steps"] == 3
    a = load_file(str(Path(straight["run_dir"]) / "checkpoints/latest/model.safetensors"))
    b = load_file(str(resume / "model.safetensors"))
    assert a.keys() == b.keys()
    for name, value in a.items():
        assert torch.equal(value, b[name]), name
    batch = make_fake_batch(policy.config, batch_size=2, seed=3)
    with torch.no_grad():
        out = VLAGRPolicy.from_pretrained(resume).goal_outputs(batch)
        straight_dir = Path(straight["run_dir"]) / "checkpoints" / "latest"
        expected = VLAGRPolicy.from_pretrained(straight_dir).goal_outputs(batch)
    torch.testing.assert_close(out["pixel_logits"], expected["pixel_logits"], rtol=0, atol=0)
    torch.testing.assert_close(out["visible_logits"], expected["visible_logits"], rtol=0, atol=0)


def test_a_category_output_is_warm_started_from_a_goal_head_without_one(tmp_path, caplog):
    base = _run(tmp_path, **{"training.steps": 1, "training.run_name": "base"})
    init = Path(base["run_dir"]) / "checkpoints" / "latest"
    warm = {
        "training.steps": 1,
        "training.run_name": "warm",
        "training.init_from": str(init),
        "model.goal_head.category_head": True,
    }
    with pytest.raises(CheckpointError, match="2 missing"):
        _run(tmp_path, **warm)
    caplog.set_level("INFO")
    _run(tmp_path, **warm, **{"training.init_allow_missing": True})
    assert "goal_head.category_logit.weight" in caplog.text
    rows = read_metrics(tmp_path / "runs" / "warm" / "metrics.jsonl")
    assert {"train/category_bce", "train/category_dice"} <= set(rows[0])


def _count_calls(module) -> list:
    calls: list = []
    module.register_forward_hook(lambda *args: calls.append(1))
    return calls


def test_the_room_check_is_one_field_of_the_tick_percept_and_reaches_the_navigator():
    model = _model(
        "model.schedule.control_frequency_hz=10",
        "model.schedule.planning_frequency_hz=3.3",
        "model.room_type.enabled=true",
        "model.navigator.goal_checks.room_reject_threshold=0.5",
    )
    system, perception = model.dual_system, model.perception
    assert perception.room_type is model.room_type  # the policy's classifier is S2's check
    calls = _count_calls(model.room_type)
    kitchen = {**_obs(), "instruction": "find the chair in the kitchen"}
    assert 0.0 < perception.perceive(kitchen).room_match < 1.0 and len(calls) == 1
    perception.reset()
    assert perception.perceive(_obs()).room_match == 1.0  # "find the chair" names no room
    assert len(calls) == 1  # no room named: the classifier is not asked
    model.reset()
    for _ in range(7):
        model.select_action(kitchen)
    assert len(calls) == 4  # once per S2 tick: steps 0, 3, 6
    perceive = perception.perceive
    perception.perceive = lambda obs: dataclasses.replace(perceive(obs), room_match=0.25)
    model.reset()
    for _ in range(7):
        model.select_action(_obs())
    assert list(system.navigator.checks.room_matches) == [0.25, 0.25, 0.25]
    # without the classifier S2 passes 1 on every tick
    plain = _model()
    assert plain.room_type is None and plain.perception.room_type is None
    plain.select_action(kitchen)
    assert list(plain.dual_system.navigator.checks.room_matches) == [1.0]


def test_the_object_checks_read_the_ticks_likelihood_and_reach_the_navigator():
    model = _model(
        "model.schedule.control_frequency_hz=10",
        "model.schedule.planning_frequency_hz=3.3",
        "model.object_category.enabled=true",
        "model.navigator.goal_checks.object_reject_threshold=0.5",
    )
    system, perception = model.dual_system, model.perception
    assert perception.object_category is model.object_category  # the policy's segmenter
    goal = np.zeros((32, 32), np.float32)
    goal[8:16, 8:16] = 1.0
    likelihood = {"pixels": goal}
    model.goal_head.likelihood = lambda rgb, depth, text, network=None: (
        torch.from_numpy(likelihood["pixels"])[None],  # (1, H, W)
        torch.ones(1),  # (1,)
    )
    calls = _count_calls(model.object_category)
    p = perception.perceive(_obs())
    assert 0.0 < p.category_match < 1.0 and p.anchor is None and len(calls) == 1
    np.testing.assert_array_equal(p.likelihood, goal)
    likelihood["pixels"] = np.zeros((32, 32), np.float32)
    assert perception.perceive(_obs()).category_match is None  # too few goal pixels
    anchor = np.zeros((32, 32), np.float32)
    anchor[:, 12:20] = 1.0  # the anchor fills the middle columns of every frame
    perceive = perception.perceive
    perception.perceive = lambda obs: dataclasses.replace(
        perceive(obs), category_match=0.25, anchor=anchor
    )
    model.reset()
    for _ in range(7):
        model.select_action(_obs())
    assert system.last_percept.anchor is anchor  # steps 0, 3, 6
    assert list(system.navigator.checks.object_matches) == [0.25, 0.25, 0.25]
    assert system.navigator.checks.has_anchor and system.navigator.checks.anchor_votes.max() == 3
    plain = _model()
    assert plain.object_category is None and plain.perception.object_category is None
    plain.select_action(_obs())
    assert list(plain.dual_system.navigator.checks.object_matches) == []
    assert not plain.dual_system.navigator.checks.has_anchor


def test_the_goal_head_and_the_checks_read_the_readers_reading_not_the_words():
    from vla_gr.agent.reading import InstructionReader, Reading

    model = _model("model.room_type.enabled=true", "model.instruction_reader.enabled=true")
    assert isinstance(model.instruction_reader, InstructionReader)
    said = "yo, the couch by the telly in the kitchen"
    reading = Reading(said, "sofa", None, "kitchen", "tv_monitor", understood=True)
    model.instruction_reader.read = lambda text: reading if text == said else None
    seen = []
    likelihood = model.goal_head.likelihood
    model.goal_head.likelihood = lambda rgb, depth, text, network=None: (
        seen.extend(text) or likelihood(rgb, depth, text)
    )
    model.reset()
    model.select_action({**_obs(), "instruction": said})
    assert seen == ["find the sofa in the kitchen next to the tv"]
    assert model.reading is reading and model.declared_outcome is None
    episode = model.perception._read(said)
    assert (episode.category, episode.anchor, episode.room) == (2, 5, 0)
    plain = _model()  # no reader: the template words, the goal head reads them as said
    assert plain.instruction_reader is None
    plain.select_action(_obs())
    assert plain.reading.category == "chair" and plain.reading.understood


def test_a_request_not_understood_is_not_acted_on_and_declared():
    from vla_gr.agent.reading import Reading

    model = _model("model.instruction_reader.enabled=true")
    refused = Reading("find the piano", reason="'piano' is nothing I know", understood=False)
    model.instruction_reader.read = lambda text: refused
    planned = []
    model.dual_system.navigator.plan = lambda *a, **k: planned.append(1)
    model.reset()
    for _ in range(4):  # however often it is asked, no motion and no STOP
        action = model.select_action({**_obs(), "instruction": "find the piano"})
        assert action.tolist() == [0.0, 0.0, 0.0]
    assert model.declared_outcome == "not_understood" and model.reading is refused
    assert planned == []  # S2 never planned
    model.reset()
    assert model.declared_outcome is None and model.reading is None
    plain = _model()  # without a reader, a request naming no template category is refused too
    plain.select_action({**_obs(), "instruction": "qwzx plorf"})
    assert plain.declared_outcome == "not_understood"


def test_relation_candidates_add_the_instructed_categorys_pixels_once_per_frame():
    model = _model("model.object_category.enabled=true")
    segmenter = model.object_category
    plant = 1 + model.config.object_category.categories.index("plant")
    with torch.no_grad():  # the segmenter sees a plant at every pixel
        segmenter.logits.weight.zero_()
        segmenter.logits.bias.fill_(-20.0)
        segmenter.logits.bias[plant] = 20.0
    calls = []
    segmenter.register_forward_hook(lambda *args: calls.append(1))

    def said(text: str) -> dict:
        return {**_obs(), "instruction": text}

    texts = (
        "find the plant near the sofa",  # a relation without a colour: candidates
        "find the green plant near the sofa?",  # a colour: the goal head alone
        "find the plant",  # no relation: the goal head alone
        "find the chair near the sofa",  # candidates are chair pixels: there are none
    )
    perceive = model.perception.perceive
    head = {t: perceive(said(t)).likelihood for t in texts}
    assert max(float(h.max()) for h in head.values()) < 0.99  # off by default
    model.config.object_category.relation_candidates = True
    relation = said(texts[0])
    calls.clear()
    percept = perceive(relation)  # candidates, category match and anchor: one pass
    np.testing.assert_allclose(percept.likelihood, 1.0, atol=1e-6)
    assert len(calls) == 1 and percept.anchor is not None
    changed = {**relation, "rgb": relation["rgb"] + 1}  # another frame: a new pass
    perceive(changed)
    assert len(calls) == 2
    for text in texts[1:]:
        np.testing.assert_allclose(perceive(said(text)).likelihood, head[text], atol=1e-6)


def test_anchor_not_goal_zeroes_the_goal_likelihood_on_the_anchors_pixels_only():
    model = _model("model.object_category.enabled=true")
    classes = 1 + len(model.config.object_category.categories)
    sofa = 1 + model.config.object_category.categories.index("sofa")
    probs = torch.zeros(1, classes, 32, 32)  # background everywhere, a sofa in the left half
    probs[:, 0, :, 16:] = 1.0
    probs[:, sofa, :, :16] = 1.0
    model.object_category.probabilities = lambda rgb, depth, network=None: probs

    def said(text: str) -> dict:
        return {**_obs(), "instruction": text}

    relation, plain = said("find the chair near the sofa"), said("find the chair")

    def goal_likelihood(obs: dict) -> np.ndarray:
        return model.perception.perceive(obs).likelihood  # (32, 32)

    before = {o["instruction"]: goal_likelihood(o) for o in (relation, plain)}
    model.config.object_category.anchor_not_goal = True
    after = goal_likelihood(relation)  # (32, 32)
    np.testing.assert_array_equal(after[:, :16], 0.0)  # the sofa's pixels: not the goal
    np.testing.assert_allclose(after[:, 16:], before[relation["instruction"]][:, 16:], atol=1e-6)
    assert float(before[relation["instruction"]][:, :16].max()) > 0.0
    # no relation, or the anchor is the goal's own category: the goal head's likelihood as is
    np.testing.assert_allclose(goal_likelihood(plain), before[plain["instruction"]])
    same = said("find the sofa near the sofa")
    model.config.object_category.anchor_not_goal = False
    head = goal_likelihood(same)
    model.config.object_category.anchor_not_goal = True
    np.testing.assert_allclose(goal_likelihood(same), head, atol=1e-6)


def test_the_checks_read_the_instruction_once_per_episode(monkeypatch):
    import vla_gr.agent.perception.percept as agent_module

    model = _model(
        "model.object_category.enabled=true",
        "model.room_type.enabled=true",
        "model.object_category.relation_candidates=true",
    )
    reads = []
    real = agent_module.template_reading
    monkeypatch.setattr(
        agent_module, "template_reading", lambda text, *a: reads.append(text) or real(text, *a)
    )
    obs = {**_obs(), "instruction": "find the plant near the sofa in the kitchen"}
    model.reset()
    ticks = 0
    for _ in range(3 * model.dual_system.plan_every):
        model.select_action(obs)
        ticks = model.dual_system.navigator.ticks
    assert ticks >= 3 and reads == [obs["instruction"]]  # room, object and relation checks
    reading = model.perception.read(obs["instruction"])
    assert reading.fields() == {"category": "plant", "color": None, "room": "kitchen",
                                "anchor": "sofa"}  # fmt: skip
    model.reset()  # a new episode reads it again
    model.select_action(obs)
    assert reads == [obs["instruction"]] * 2


def test_depth_guard_hands_the_pursuit_check_to_the_learned_s1():
    guarded = _model("model.s1.kind=learned", "model.s1.depth_guard=true")
    assert guarded.dual_system.follower.guard == guarded.config.pursuit
    assert _model("model.s1.kind=learned").dual_system.follower.guard is None
