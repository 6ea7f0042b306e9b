"""VLAGRPolicy: the LeRobot-style interface, action queues, normalisation, learning."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.helpers import fake_batch, tiny_policy
from vla_gr.data.normalize import MinMaxNormalizer


def _env_obs(t: int, batch: int | None = None) -> dict:
    """An environment observation whose pose x encodes the step t."""
    rgb = np.full((16, 16, 3), t % 256, np.uint8)
    depth = np.ones((16, 16, 1), np.float32)
    pose = np.array([t, 0.0, 0.0], np.float32)
    if batch is None:
        return {"rgb": rgb, "depth": depth, "pose": pose, "instruction": "find the sofa"}
    return {
        "rgb": np.stack([rgb] * batch),
        "depth": np.stack([depth] * batch),
        "pose": np.stack([pose] * batch),
        "instruction": ["find the sofa"] * batch,
    }


class _Recorder:
    """Replaces predict_action_chunk: chunk k has actions[b, h] = (k, h, b)."""

    def __init__(self, horizon: int):
        self.horizon, self.histories = horizon, []

    def __call__(self, obs):
        self.histories.append(obs["pose"][:, :, 0].clone())  # (B, T) step ids
        k, B = len(self.histories) - 1, obs["pose"].shape[0]
        chunk = torch.zeros(B, self.horizon, 3)
        chunk[..., 0] = k
        chunk[..., 1] = torch.arange(self.horizon, dtype=torch.float32)
        chunk[..., 2] = torch.arange(B, dtype=torch.float32)[:, None]
        return chunk


def test_select_action_replans_exactly_every_n_action_steps():
    policy = tiny_policy(0, horizon=6, n_action_steps=3)
    rec = _Recorder(6)
    policy.predict_action_chunk = rec
    actions = [policy.select_action(_env_obs(t)) for t in range(10)]
    assert len(rec.histories) == 4  # replanned at t = 0, 3, 6, 9
    for t, a in enumerate(actions):
        assert a.shape == (3,) and a.dtype == np.float32  # what env.step takes
        assert a[0] == t // 3 and a[1] == t % 3  # chunk t//3, index t%3
    # Observation history (n_obs_steps=2) at each replanning step: (t - 1, t), o0 repeated.
    assert [h[0].tolist() for h in rec.histories] == [[0, 0], [2, 3], [5, 6], [8, 9]]


def test_reset_clears_queues():
    policy = tiny_policy(0, horizon=6, n_action_steps=3)
    rec = _Recorder(6)
    policy.predict_action_chunk = rec
    policy.select_action(_env_obs(0))
    policy.select_action(_env_obs(1))
    policy.reset()
    a = policy.select_action(_env_obs(7))
    assert len(rec.histories) == 2 and a[0] == 1 and a[1] == 0
    assert rec.histories[1][0].tolist() == [7, 7]  # history restarted from the new episode


def test_batched_select_action_and_chunk_shape():
    policy = tiny_policy(0, objective="flow_matching", sampler="euler")
    policy.eval()
    a = policy.select_action(_env_obs(0, batch=3))
    assert a.shape == (3, 3) and a.dtype == np.float32
    chunk = policy.predict_action_chunk(fake_batch(policy.config, 2))
    assert chunk.shape == (2, policy.config.horizon, 3)
    assert chunk.abs().max() <= 1.0 and not chunk.requires_grad


def _row(t: int, env: int) -> dict:
    """Env ``env``'s observation at its step ``t`` (pixels, pose and request differ per env)."""
    obs = _env_obs(t)
    rgb = (obs["rgb"].astype(np.int64) + 37 * env + np.arange(16)[:, None, None]) % 256
    pose = np.array([0.1 * t, 0.2 * env, 0.05 * t], np.float32)
    said = ["find the sofa", "find the bed"][env]
    return {**obs, "rgb": rgb.astype(np.uint8), "pose": pose, "instruction": said}


def test_a_batch_gives_each_env_its_lone_actions_and_a_done_env_restarts_alone():
    policy = tiny_policy(0, horizon=6, n_action_steps=3).eval()

    def lone(env: int, steps: range) -> np.ndarray:
        policy.reset()
        return np.stack([policy.select_action(_row(t - steps[0], env)) for t in steps])  # (T, 3)

    # env 0: an episode of 5 rows (the last one ends it), a new episode from step 5; env 1: 9
    expected = [np.concatenate([lone(0, range(4)), np.zeros((1, 3)), lone(0, range(5, 9))])]
    expected.append(lone(1, range(9)))
    sizes = []
    predict = policy.predict_action_chunk
    policy.predict_action_chunk = lambda h: sizes.append(len(h["instruction"])) or predict(h)
    policy.reset()
    got = []
    for t in range(9):
        rows = [_row(t if t < 5 else t - 5, 0), _row(t, 1)]
        batch = {k: np.stack([r[k] for r in rows]) for k in ("rgb", "depth", "pose")}
        batch["instruction"] = [r["instruction"] for r in rows]
        got.append(policy.select_action(batch, done=np.array([t == 4, False])))  # (2, 3)
    got = np.stack(got)  # (T, 2, 3)
    for env in (0, 1):
        np.testing.assert_allclose(got[:, env], expected[env], atol=1e-6)
    # chunks: both envs at t = 0, 3; env 0 alone at its restart (5) and 8, env 1 alone at 6
    assert sizes == [2, 2, 1, 1, 1]


def test_action_normalisation_round_trip_and_use():
    policy = tiny_policy(0)
    norm = MinMaxNormalizer.from_min_max([0.0, -2.0, -1.0], [1.0, 2.0, 1.0])
    policy.set_normalization({"action": norm, "pose": norm})
    x = torch.tensor([[0.5, 2.0, -1.0]])
    torch.testing.assert_close(policy.normalize_action(x), torch.tensor([[0.0, 1.0, -1.0]]))
    torch.testing.assert_close(policy.unnormalize_action(policy.normalize_action(x)), x)
    assert "action_scale" in policy.state_dict()  # stats travel with the weights
    with pytest.raises(ValueError, match="pose"):
        policy.set_normalization({"action": norm})


def test_forward_validates_shapes():
    policy = tiny_policy(0)
    batch = fake_batch(policy.config, 2)
    batch["action"] = batch["action"][:, :2]
    with pytest.raises(ValueError, match="action"):
        policy(batch)


def _seeded_loss(policy, batch) -> float:
    torch.manual_seed(123)  # the same flow-matching noise and times before and after
    with torch.no_grad():
        return policy(batch)["loss"].item()


@pytest.mark.parametrize(("objective", "factor"), [("l1", 0.7), ("flow_matching", 0.9)])
def test_loss_is_finite_and_decreases_on_a_tiny_overfit(objective, factor):
    policy = tiny_policy(0, objective=objective, dim=32, hidden_dim=32, horizon=8)
    batch = fake_batch(policy.config, 4, seed=4)
    before = _seeded_loss(policy, batch)
    opt = torch.optim.Adam(policy.parameters(), lr=3e-3)
    for _ in range(60):
        loss = policy(batch)["loss"]
        assert torch.isfinite(loss)
        opt.zero_grad()
        loss.backward()
        opt.step()
    after = _seeded_loss(policy, batch)
    assert after < factor * before, (before, after)


@pytest.mark.parametrize(
    "instruction, says",
    [
        (None, "got NoneType"),
        (b"find the sofa", "got bytes"),
        (["find the sofa", None], "holds a NoneType"),
        ([b"find the sofa"], "holds a bytes"),
        (42, "got int"),
    ],
)
def test_non_string_instruction_is_a_clear_type_error(instruction, says):
    policy = tiny_policy(0)
    obs = dict(_env_obs(0), instruction=instruction)
    if isinstance(instruction, list):
        obs = dict(_env_obs(0, batch=len(instruction)), instruction=instruction)
    with pytest.raises(TypeError, match=rf"obs\['instruction'\] must be a string .*{says}"):
        policy.select_action(obs)
    batch = fake_batch(policy.config, 2)
    batch["instruction"] = [instruction, "find the sofa"]
    with pytest.raises(TypeError, match=r"batch\['instruction'\] must be a string"):
        policy(batch)


def test_string_arrays_are_instructions():
    policy = tiny_policy(0)
    obs = dict(_env_obs(0, batch=2), instruction=np.array(["find the sofa", "find the bed"]))
    assert policy.select_action(obs).shape == (2, 3)
