"""The dual-system agent's goal head: what it builds, its loss, config checks, and training
(2 steps, resume, ``from_pretrained``) through the generic trainer."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from tests.helpers import train_overrides
from vla_gr.configs import ConfigError, load_config
from vla_gr.core.grounding import goal_head_loss
from vla_gr.data.dataset import EpisodeWindowDataset
from vla_gr.policy import VLAGRPolicy, make_fake_batch
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
    assert model.has_goal_head
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


def test_inference_is_left_to_the_s2_navigator():
    model = _model()
    obs = {
        "rgb": torch.zeros(32, 32, 3, dtype=torch.uint8),
        "depth": torch.ones(32, 32, 1),
        "pose": torch.zeros(3),
        "instruction": "find the chair",
    }
    with pytest.raises(RuntimeError, match="needs the S2 navigator"):
        model.select_action(obs)
    with pytest.raises(RuntimeError, match="needs the S2 navigator"):
        model.predict_action_chunk(obs)


def test_end_to_end_is_the_default_and_has_no_goal_head():
    _, cfg = load_config("config_debug")
    model = VLAGRPolicy(cfg.model)
    assert cfg.model.agent == "end_to_end" and not model.has_goal_head
    assert not hasattr(model, "goal_head")
    with pytest.raises(RuntimeError, match="no goal head"):
        model.goal_outputs(make_fake_batch(cfg.model))


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["model.agent=s2"], r"model\.agent"),
        ([*DUAL, "env.image_size=36"], r"model\.image_size=36 must be divisible by 8"),
        ([*DUAL, "model.freeze=[vision]"], r"model\.freeze.*dual_system"),
        ([*DUAL, "training.eval_episodes=1"], r"training\.eval_episodes=1.*S2 inference"),
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
