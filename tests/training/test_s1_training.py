"""S1 training: teacher chunks within episodes, the verified data folders, and one round end
to end (an eval run of the shipped agent on train episodes -> relabelled -> S1 trained ->
a checkpoint that loads with the learned S1 and the init's S2 untouched)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from vla_gr.agent.followers import LearnedFollower, S1Policy
from vla_gr.agent.followers.s1_inputs import plan_vector_size, pool_rgbd
from vla_gr.agent.navigator import NavPlan
from vla_gr.checkpoint import read_checkpoint
from vla_gr.configs import load_config
from vla_gr.core.dual_system import S1Config
from vla_gr.data.collect import make_env
from vla_gr.envs.local_teacher import LocalTeacherConfig
from vla_gr.errors import UserError
from vla_gr.evaluate import evaluate, expand_aliases
from vla_gr.policy import VLAGRPolicy
from vla_gr.training.dagger import train_run
from vla_gr.training.s1 import S1Batches, _validate, plans_without_s2, train_s1
from vla_gr.training.s1_data import load_s1_data, relabel_run, write_s1_part

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"


def _arrays(episodes: list[int], s1: S1Config, seed: int = 0) -> dict[str, np.ndarray]:
    """S1 data with frame i's teacher (v, w, stop) = (i, -i, stop every 4th frame)."""
    rng = np.random.default_rng(seed)
    n, s = len(episodes), s1.image_size
    i = np.arange(n, dtype=np.float32)
    return {
        "rgb": rng.integers(0, 256, (n, 3, s, s)).astype(np.uint8),
        "depth": rng.uniform(0, 9, (n, 1, s, s)).astype(np.float16),
        "plan": rng.standard_normal((n, plan_vector_size(s1.path_points))).astype(np.float32),
        "teacher": np.stack([i, -i, np.where(i % 4 == 3, 1.0, -1.0)], 1).astype(np.float32),
        "episode": np.asarray(episodes, np.int64),
    }


def test_chunks_stay_inside_their_episode_and_repeat_its_last_label():
    s1 = S1Config()
    data = _arrays([5, 5, 5, 7, 7, 9, 4, 4], s1)
    batches = S1Batches(data, horizon=4, indices=np.arange(8))
    out = batches.batch(np.arange(8))
    expected = [
        [0, 1, 2, 2], [1, 2, 2, 2], [2, 2, 2, 2],  # episode 5: frames 0-2
        [3, 4, 4, 4], [4, 4, 4, 4],  # episode 7
        [5, 5, 5, 5],  # episode 9: one frame
        [6, 7, 7, 7], [7, 7, 7, 7],  # episode 4
    ]  # fmt: skip
    np.testing.assert_array_equal(out["chunk"][..., 0].numpy(), expected)
    np.testing.assert_array_equal(out["chunk"][..., 1].numpy(), -np.asarray(expected))
    assert out["chunk"].shape == (8, 4, 2) and out["chunk"].dtype == torch.float32
    assert out["stop"].tolist() == [0, 0, 0, 1, 0, 0, 0, 1]  # the frame's own STOP, as 0/1
    assert out["rgb"].dtype == torch.uint8 and torch.equal(
        out["rgb"], torch.from_numpy(data["rgb"])
    )
    assert out["depth"].dtype == torch.float32
    np.testing.assert_array_equal(out["depth"].numpy(), data["depth"].astype(np.float32))
    np.testing.assert_array_equal(out["plan"].numpy(), data["plan"])
    # a split draws only its own frames, and their chunks still never leave the episode
    split = S1Batches(data, horizon=3, indices=np.array([3, 4]))
    drawn = split.sample(16, np.random.default_rng(0))
    assert set(drawn["chunk"][:, 0, 0].tolist()) <= {3.0, 4.0}
    assert drawn["chunk"][:, :, 0].max() == 4.0
    assert [b["chunk"].shape[0] for b in S1Batches(data, 2, np.arange(8)).ordered(3)] == [3, 3, 2]


def _folder(tmp_path: Path, name: str, s1: S1Config, parts: list[list[int]]) -> Path:
    out = tmp_path / name
    for k, episodes in enumerate(parts):
        write_s1_part(out, f"part-{k:04d}", _arrays(episodes, s1, seed=k), s1, source="test")
    return out


def test_load_verifies_parts_and_keeps_episodes_of_different_parts_apart(tmp_path):
    s1 = S1Config()
    folder = _folder(tmp_path, "a", s1, [[0, 0, 0, 0], [0, 0, 1]])
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["image_size"] == 32 and manifest["plan_dim"] == plan_vector_size(s1.path_points)
    assert manifest["parts"]["part-0000.safetensors"]["frames"] == 4
    assert manifest["parts"]["part-0000.safetensors"]["stops"] == 1
    assert manifest["parts"]["part-0001.safetensors"]["episodes"] == 2
    data = load_s1_data([folder, _folder(tmp_path, "b", s1, [[3, 3]])], s1)
    assert len(data["episode"]) == 9 and data["depth"].dtype == np.float16
    assert len(np.unique(data["episode"])) == 4  # episode 0 of part 0 != episode 0 of part 1
    np.testing.assert_array_equal(data["teacher"][:4], _arrays([0] * 4, s1)["teacher"])
    # the last frame of part 0 does not chunk into part 1's frames (teacher v 0, 1, 2)
    chunk = S1Batches(data, 3, np.arange(9)).batch(np.array([3]))["chunk"][0, :, 0]
    assert chunk.tolist() == [3.0, 3.0, 3.0]


def test_load_refuses_damaged_missing_and_foreign_parts(tmp_path):
    s1 = S1Config()
    folder = _folder(tmp_path, "data", s1, [[0, 0], [1, 1]])
    part = folder / "part-0001.safetensors"
    raw = bytearray(part.read_bytes())
    raw[-5] ^= 0x01  # one bit of the last array's data
    part.write_bytes(bytes(raw))
    with pytest.raises(UserError, match=f"{part}.*damaged.*sha256"):
        load_s1_data([folder], s1)
    part.unlink()
    with pytest.raises(UserError, match=f"{part} is missing"):
        load_s1_data([folder], s1)

    other = _folder(tmp_path, "other", s1, [[0]])
    for changed in (
        S1Config(image_size=16, channels=[8, 16]),
        S1Config(path_points=[0.5, 1.0]),
    ):
        with pytest.raises(UserError, match=f"{other} was made for S1 inputs"):
            load_s1_data([other], changed)
        with pytest.raises(UserError, match="another layout"):
            write_s1_part(other, "part-0009", _arrays([2], changed), changed)
    with pytest.raises(UserError, match="not an S1 data folder"):
        load_s1_data([tmp_path], s1)
    with pytest.raises(ValueError, match="different lengths"):
        write_s1_part(other, "part-0001", _arrays([2], s1) | {"episode": np.zeros(2)}, s1)


def test_training_needs_an_episode_to_train_on_and_one_to_validate(tmp_path):
    folder = _folder(tmp_path, "one", S1Config(), [[4, 4, 4, 4]])
    with pytest.raises(UserError, match="at least 2 episodes"):
        train_s1(SHIPPED, tmp_path / "out", [folder], steps=1, batch_size=2)
    assert not (tmp_path / "out").exists()
    # two episodes: one trains, one validates, whatever the validation fraction asks
    two = _folder(tmp_path, "two", S1Config(), [[4, 4, 5, 5]])
    summary = train_s1(SHIPPED, tmp_path / "out", [two], steps=1, batch_size=2, val_fraction=0.9)
    assert np.isfinite(summary["best_val_loss"]) and (tmp_path / "out" / "manifest.json").exists()


def test_validation_leaves_the_training_randomness_alone():
    s1 = S1Config()
    torch.manual_seed(0)
    policy = SimpleNamespace(s1=S1Policy(s1))
    batches = S1Batches(_arrays([0, 0, 1, 1, 1], s1), s1.head.horizon, np.arange(5))
    torch.manual_seed(5)
    state = torch.get_rng_state()
    first = _validate(policy, batches, 2)
    assert torch.equal(torch.get_rng_state(), state)
    torch.manual_seed(6)
    assert _validate(policy, batches, 2) == first  # comparable from one validation to the next
    assert policy.s1.training


def test_without_s2_s1_trains_on_the_plan_vectors_it_reads_at_inference(tmp_path, monkeypatch):
    s1 = S1Config(use_s2=False)
    episode = np.array([4] * 13 + [5] * 3)
    planless = plans_without_s2(episode, s1)
    follower = LearnedFollower(S1Policy(s1))
    assert not planless[:, :-1].any()
    assert planless[:, -1].tolist() == pytest.approx(
        [*np.minimum(np.arange(13), 10) / 10, 0, 0.1, 0.2]
    )
    rgb, depth = np.zeros((32, 32, 3), np.uint8), np.ones((32, 32, 1), np.float32)
    for t in range(13):  # what the follower reads at every step of an episode
        pose = np.array([0.1 * t, 0.0, 0.0])
        if t % 3 == 0:
            follower.set_plan(NavPlan(np.ones((2, 2)), "approach", 0.5, False), pose)
        np.testing.assert_array_equal(planless[t], follower.inputs(rgb, depth, pose)["plan"])
        follower.act(depth, pose, rgb)

    seen = []

    class Recording(S1Batches):
        def __init__(self, data, horizon, indices):
            seen.append(data["plan"].copy())
            super().__init__(data, horizon, indices)

    monkeypatch.setattr("vla_gr.training.s1.S1Batches", Recording)
    folder = _folder(tmp_path, "data", S1Config(), [[4] * 13 + [5] * 3])
    train_s1(SHIPPED, tmp_path / "with", [folder], steps=1, batch_size=2)
    np.testing.assert_array_equal(seen[-1], load_s1_data([folder], S1Config())["plan"])
    train_s1(SHIPPED, tmp_path / "without", [folder], steps=1, batch_size=2,
             settings=["s1.use_s2=false"])  # fmt: skip
    np.testing.assert_array_equal(seen[-1], planless)


# ------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def round0(tmp_path_factory) -> tuple[Path, Path]:
    """An eval run of the shipped agent on train episodes 2-3 (40 steps at most; it reaches
    the goal of episode 2 and STOPs there) and its relabelled S1 data."""
    tmp = tmp_path_factory.mktemp("s1round")
    run = tmp / "run"
    args = [f"output_dir={run}", f"checkpoint={SHIPPED}", "split=train", "first_episode=2",
            "num_episodes=2", "workers=1", "eval.progress=false", "eval.video_successes=0",
            "eval.video_per_cause=0"]  # fmt: skip
    evaluate(load_config("config_cpu", [*expand_aliases(args), "env.max_episode_steps=40"])[1])
    manifest = relabel_run(run, SHIPPED, tmp / "data")
    assert manifest["parts"]["part-0000.safetensors"]["episodes"] == 2
    return run, tmp / "data"


def test_relabelled_data_is_the_replayed_episode_with_stop_only_at_the_goal(round0):
    run, data_dir = round0
    s1 = VLAGRPolicy.from_pretrained(SHIPPED).config.s1
    data = load_s1_data([data_dir], s1)
    _, rows, env_kwargs = train_run(run)
    env = make_env(env_kwargs | {"semantic": False})
    stop_within = env_kwargs["success_distance"] - LocalTeacherConfig().stop_margin
    assert (data["teacher"][:, :2] >= -1).all() and (data["teacher"][:, :2] <= 1).all()
    assert set(data["teacher"][:, 2].tolist()) <= {-1.0, 1.0}
    stop_slot = 2 * len(s1.path_points) + 2 + 3
    start = 0
    for row in rows:
        steps = len(row["actions"])
        frames = slice(start, start + steps)
        start += steps
        assert (data["episode"][frames] == data["episode"][frames][0]).all()
        obs, info = env.reset(options={"episode": int(row["episode_index"])})
        distances, rgbs, depths = [], [], []
        for action in row["actions"]:
            distances.append(info["distance_to_goal"])  # at the frame the label is for
            small_rgb, small_depth = pool_rgbd(obs["rgb"], obs["depth"], s1.image_size)
            rgbs.append(small_rgb)
            depths.append(small_depth)
            obs, _, terminated, truncated, info = env.step(np.asarray(action, np.float32))
        assert terminated or truncated
        # S1's inputs are what it sees at inference, frame by frame
        np.testing.assert_array_equal(data["rgb"][frames], np.stack(rgbs))
        np.testing.assert_allclose(data["depth"][frames], np.stack(depths), rtol=1e-3, atol=1e-3)
        stops = data["teacher"][frames, 2] > 0
        assert (np.asarray(distances)[stops] <= stop_within).all(), (row["episode_index"], stops)
        assert (data["plan"][frames][stops, stop_slot] == 1.0).all()  # S2 asked for them
        if stops.any():  # the agent's S2 asked for STOP, and the agent stopped there
            assert terminated and row["metrics"]["success"] == info["success"] == 1.0
    assert start == len(data["episode"])  # every recorded step, nothing else
    assert (data["teacher"][:, 2] > 0).sum() >= 1  # the STOP check is not vacuous
    env.close()


def test_trained_s1_checkpoint_loads_learned_with_the_init_s2(round0, tmp_path):
    _, data_dir = round0
    out = tmp_path / "s1"
    summary = train_s1(SHIPPED, out, [data_dir], steps=3, batch_size=16, eval_every=2)
    assert [row["step"] for row in summary["history"]] == [2, 3]
    assert np.isfinite(summary["best_val_loss"])
    assert summary["best_val_loss"] == min(r["val_loss"] for r in summary["history"])

    written = read_checkpoint(out)  # verifies the manifest
    assert OmegaConf.create(written.config_yaml).model.s1.kind == "learned"
    assert written.state["s1_steps"] == 3
    policy = VLAGRPolicy.from_pretrained(out)
    assert policy.config.s1.kind == "learned"
    assert isinstance(policy.dual_system.follower, LearnedFollower)
    init = read_checkpoint(SHIPPED).model
    assert written.model.keys() == init.keys()
    for name, value in init.items():
        if not name.startswith("s1."):
            assert torch.equal(written.model[name], value), name  # S2 bit for bit
    assert any(not torch.equal(written.model[k], v) for k, v in init.items() if k[:3] == "s1.")
    loaded = dict(policy.state_dict())
    for name, value in written.model.items():
        assert torch.equal(loaded[name], value), name
    # it drives: one step on a real observation
    env = make_env({"split": "train", "image_size": 64})
    obs, _ = env.reset(options={"episode": 2})
    policy.reset()
    action = policy.select_action(obs)
    assert action.shape == (3,) and np.abs(action).max() <= 1.0
    env.close()


def test_an_s1_of_another_width_is_trained_from_its_settings(round0, tmp_path):
    _, data_dir = round0
    train_s1(SHIPPED, tmp_path / "narrow", [data_dir], steps=1, batch_size=8,
             settings=["s1.dim=32", "s1.head.hidden_dim=16"])  # fmt: skip
    policy = VLAGRPolicy.from_pretrained(tmp_path / "narrow")
    assert policy.config.s1.dim == 32 and policy.s1.head.context_dim == 32
    with pytest.raises(UserError, match="key under s1"):
        train_s1(SHIPPED, tmp_path / "x", [data_dir], steps=1, settings=["dim=32"])
