"""Closed-loop rollouts: the loop (budget, STOP, resets) and the metric summary."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import tiny_policy
from vla_gr.envs.metrics import AGGREGATE_KEYS
from vla_gr.evaluate import rollout_policy, summarize

ENV = {"split": "val", "image_size": 16, "max_episode_steps": 6}
KEYS = ("success", "spl", "soft_spl", "collisions", "collision_rate", "distance_to_goal")


class Scripted:
    """A hand-made policy (the interface of ``vla_gr.policy.NavigationPolicy``): always the
    same action; counts its resets."""

    last_timings: dict[str, float] = {}  # one part: the decision

    def __init__(self, action) -> None:
        self.action = np.asarray(action, dtype=np.float32)  # (3,)
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def select_action(self, obs) -> np.ndarray:
        assert obs["rgb"].shape == (16, 16, 3)
        return self.action[None]  # (1, 3)

    def episode_summary(self) -> dict:
        return {}


def test_tiny_untrained_policy_gives_one_info_with_the_metrics_within_budget():
    policy = tiny_policy()
    policy.train()
    infos = rollout_policy(policy, ENV, [0], "cpu")
    assert len(infos) == 1
    assert all(k in infos[0] for k in KEYS)
    assert 1 <= infos[0]["steps"] <= ENV["max_episode_steps"]
    assert infos[0]["episode_index"] == 0
    assert policy.training  # mode restored after the rollout
    again = rollout_policy(policy, ENV, [0], "cpu")  # deterministic head: same episode
    assert again[0]["steps"] == infos[0]["steps"]
    assert again[0]["path_length"] == pytest.approx(infos[0]["path_length"])


def test_a_policy_that_never_stops_is_truncated_at_the_budget():
    policy = Scripted([1.0, 0.3, -1.0])
    infos = rollout_policy(policy, ENV, [0, 1], "cpu")
    assert policy.resets == 2
    assert [i["steps"] for i in infos] == [6, 6]
    assert [i["episode_index"] for i in infos] == [0, 1]
    assert all(i["success"] == 0.0 and i["path_length"] > 0 for i in infos)


def test_always_stop_succeeds_only_when_it_starts_within_the_success_distance():
    policy = Scripted([0.0, 0.0, 1.0])
    infos = rollout_policy(policy, {**ENV, "success_distance": 1.0}, [0, 1, 2], "cpu")
    for info in infos:
        assert info["steps"] == 1 and info["path_length"] == 0.0
        assert info["success"] == float(info["geodesic_start_distance"] <= 1.0)
    normal = [i for i in infos if i["geodesic_start_distance"] > 1.0]
    assert normal and all(i["success"] == 0.0 and i["spl"] == 0.0 for i in normal)
    # A success distance beyond every start distance turns the same STOPs into successes.
    far = rollout_policy(policy, {**ENV, "success_distance": 1000.0}, [0], "cpu")
    assert far[0]["success"] == 1.0 and far[0]["spl"] == 1.0  # l = 0, l* > 0: efficiency 1


def test_summarize_averages_the_episode_infos():
    infos = rollout_policy(Scripted([1.0, -0.5, -1.0]), ENV, [0, 3], "cpu")
    out = summarize(infos)
    assert out["episodes"] == 2
    for key in AGGREGATE_KEYS:
        assert out[key] == pytest.approx((infos[0][key] + infos[1][key]) / 2)


def test_rollout_needs_episodes():
    with pytest.raises(ValueError, match="episodes"):
        rollout_policy(Scripted([0, 0, 1]), ENV, [], "cpu")


def test_rollout_leaves_the_callers_torch_random_stream_alone():
    import torch

    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    rollout_policy(Scripted([0.0, 0.0, 1.0]), ENV, [0, 1], "cpu")  # seeds each episode
    assert torch.equal(torch.rand(3), expected)
