"""The object-category stage: per-pixel labels from the world's geometry agree with the
renderer's segmentation, and a trained segmenter is written into the agent with the rest
untouched and S2's object check on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from vla_gr.checkpoint import read_checkpoint
from vla_gr.cli import main
from vla_gr.envs.expert import GeodesicExpert
from vla_gr.envs.house import generate_house
from vla_gr.envs.nav_env import ObjectNavEnv
from vla_gr.envs.scene import CATEGORIES
from vla_gr.errors import UserError
from vla_gr.policy import VLAGRPolicy
from vla_gr.training.agent_stage import build_agent_from, write_agent
from vla_gr.training.object_category import (
    category_frames,
    segmentation_scores,
    train_object_category,
)
from vla_gr.training.object_labels import frame_categories

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"


def test_labels_from_geometry_agree_with_the_renderers_segmentation():
    env = ObjectNavEnv(split="val", semantic=True)
    depth, pose, seen = [], [], []
    obs, _ = env.reset(options={"episode": 1})
    expert = GeodesicExpert(env)
    for _ in range(120):
        depth.append(obs["depth"])
        pose.append(obs["pose"])
        seen.append(obs["semantic"])
        obs, _, terminated, truncated, _ = env.step(expert.act(obs))
        if terminated or truncated:
            break
    env.close()
    spec = env.episode_spec
    labels = frame_categories(spec.to_dict(), np.array(pose), np.array(depth), CATEGORIES, {})
    ids = np.array(seen)  # (T, H, W) rendered instance ids
    truth = np.zeros_like(labels)  # (T, H, W)
    house = generate_house(spec.scene_seed, num_rooms=spec.num_rooms, clutter=spec.clutter)
    for obj in house.objects:
        truth[ids == obj.instance_id] = CATEGORIES.index(obj.category) + 1
    on_objects = truth > 0
    assert on_objects.sum() > 5000  # the episode does look at furniture
    assert (labels[on_objects] == truth[on_objects]).mean() > 0.95
    assert (labels[~on_objects] > 0).mean() < 0.03


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    """The shipped agent without an object-category segmenter."""
    out = tmp_path_factory.mktemp("plain") / "agent"
    policy, loaded, config = build_agent_from(
        SHIPPED, "object_category", [], keep_part=False, forced=["object_category.enabled=false"]
    )
    assert policy.object_category is None
    return write_agent(policy, loaded, config, out, {})


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """Expert episodes 2-5 of `train` (two houses) at 32 px."""
    path = tmp_path_factory.mktemp("objects") / "store.zarr"
    args = ["collect", "--config-name", "config_debug", f"collect.output={path}",
            "collect.split=train", "collect.first_episode=2", "collect.num_episodes=4"]  # fmt: skip
    assert main(args) == 0
    return path


def test_trained_segmenter_is_written_with_the_object_check_and_the_rest_untouched(
    store, plain, tmp_path
):
    frames = category_frames(store, CATEGORIES, stride=2)
    assert frames["label"].shape == (len(frames["rgb"]), 32, 32)
    assert frames["label"].dtype == np.uint8 and frames["label"].max() > 0
    out = tmp_path / "agent"
    summary = train_object_category(plain, out, frames, CATEGORIES, steps=4, batch_size=8,
                                    eval_every=2, reject_threshold=0.35,
                                    eval_frames=frames)  # fmt: skip
    assert [row["step"] for row in summary["history"]] == [2, 4]
    assert summary["best_val_mean_iou"] == max(r["mean_iou"] for r in summary["history"])
    written = read_checkpoint(out)
    model = OmegaConf.create(written.config_yaml).model
    assert (
        model.object_category.enabled
        and model.navigator.goal_checks.object_reject_threshold == 0.35
    )
    init = read_checkpoint(plain).model
    for name, value in init.items():
        assert torch.equal(written.model[name], value), name  # the rest bit for bit
    assert {k for k in written.model if k not in init} == {
        k for k in written.model if k.startswith("object_category.")
    }
    policy = VLAGRPolicy.from_pretrained(out)
    assert policy.perception.object_category is policy.object_category
    assert segmentation_scores(policy.object_category, frames) == summary["eval"]
    obs = {
        "rgb": frames["rgb"][0].transpose(1, 2, 0),
        "depth": frames["depth"][0].transpose(1, 2, 0),
        "pose": np.zeros(3, np.float32),
        "instruction": "find the sofa near the tv",
    }
    goal = np.zeros((32, 32), np.float32)
    goal[10:14, 10:14] = 0.9
    probs = policy.object_category.probabilities(
        torch.from_numpy(frames["rgb"][:1]), torch.from_numpy(frames["depth"][:1])
    )[0]  # (1 + K, 32, 32)
    expected = float(probs[CATEGORIES.index("sofa") + 1, 10:14, 10:14].mean())
    evidence = _percept(policy, obs, goal)
    assert evidence.category_match == pytest.approx(expected, rel=1e-5)
    tv = probs[CATEGORIES.index("tv_monitor") + 1].numpy()  # the anchor "tv", every pixel
    np.testing.assert_allclose(evidence.anchor, tv, rtol=1e-5)
    nothing = _percept(policy, obs, np.zeros((32, 32), np.float32))  # no goal pixels
    assert nothing.category_match is None and nothing.anchor is not None  # anchor still mapped
    assert _percept(policy, {**obs, "instruction": "find the sofa"}, goal).anchor is None
    without = _percept(VLAGRPolicy.from_pretrained(plain), obs, goal)
    assert (without.category_match, without.anchor) == (None, None)


def _percept(policy, obs: dict, goal: np.ndarray):
    """The policy's percept of ``obs`` when its goal head marks ``goal`` (H, W)."""
    policy.goal_head.likelihood = lambda rgb, depth, text, network=None: (
        torch.from_numpy(goal)[None],  # (1, H, W)
        torch.ones(1),  # (1,)
    )
    return policy.perception.perceive(obs)


def test_bad_input_is_refused_with_the_reason(store, plain, tmp_path):
    frames = category_frames(store, CATEGORIES, stride=4)
    with pytest.raises(UserError, match="frames are labelled in"):
        train_object_category(plain, tmp_path / "x", frames, CATEGORIES[::-1], steps=1)
    one_house = {k: v[frames["house"] == frames["house"][0]] for k, v in frames.items()}
    with pytest.raises(UserError, match="training needs 2 or more"):
        train_object_category(plain, tmp_path / "x", one_house, CATEGORIES, steps=1)
    with pytest.raises(UserError, match="selects none"):  # no stored episode from 9 on
        category_frames(store, CATEGORIES, first=9)
