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
    declared_outcome: str | None = None  # it never declares
    reading = None  # it reads no request

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


class FakeReading:
    """What a ``Reading`` gives the eval: ``as_dict()``."""

    def as_dict(self) -> dict:
        fields = {"category": "sofa", "color": None, "room": None, "anchor": None}
        return {**fields, "relation": None, "confidence": {"category": 0.9}, "unknown": [],
                "understood": True, "reason": None}  # fmt: skip


class DeclaresAfter(Scripted):
    """Drives forward; after its ``after``-th action it has declared ``outcome``."""

    def __init__(self, outcome: str, after: int) -> None:
        super().__init__([1.0, 0.0, -1.0])
        self.outcome, self.after, self.calls = outcome, after, 0

    def reset(self) -> None:
        super().reset()
        self.calls = 0

    def select_action(self, obs) -> np.ndarray:
        self.calls += 1
        return super().select_action(obs)

    @property
    def declared_outcome(self) -> str | None:
        return self.outcome if self.calls >= self.after else None

    @property
    def reading(self) -> FakeReading:
        return FakeReading()


@pytest.mark.parametrize("outcome", ["not_understood", "not_found"])
def test_a_declared_outcome_ends_the_episode_through_the_env_without_a_stop(outcome):
    from vla_gr.data.collect import make_env
    from vla_gr.evaluation.agents import PolicyAgent
    from vla_gr.evaluation.runner import run_episode

    env = make_env(dict(ENV, max_episode_steps=20))
    try:
        row = run_episode(env, PolicyAgent(DeclaresAfter(outcome, after=3)), 0)
        plain = run_episode(env, PolicyAgent(Scripted([1.0, 0.0, -1.0])), 0)
    finally:
        env.close()
    assert row["declared"] == outcome and row["cause"] == outcome
    assert row["stopped"] is False and row["wrong_stop"] is None and row["stopped_near"] == {}
    assert row["metrics"]["steps"] == 3 and row["metrics"]["success"] == 0.0
    assert row["metrics"]["spl"] == 0.0
    assert row["actions"] == [[1.0, 0.0, -1.0]] * 3  # the declaring step's action is recorded
    xy = row["trace"]["xy"]
    assert xy[1] != xy[0] and xy[2] != xy[1] and xy[3] == xy[2]  # declared: did not move
    assert row["reading"] == FakeReading().as_dict()
    # a policy that never declares: the budget ends it, nothing declared, no reading
    assert plain["declared"] is None and plain["reading"] is None
    assert plain["metrics"]["steps"] == 20 and plain["cause"] != outcome


def test_agents_forward_what_their_policy_or_system_declared_and_read():
    from types import SimpleNamespace

    from vla_gr.evaluation.agents import EvalAgent, PolicyAgent, UntrainedDualSystemAgent

    plain = EvalAgent()
    assert plain.declared_outcome is None and plain.reading() is None
    assert PolicyAgent(Scripted([0, 0, 0])).reading() is None
    policy = DeclaresAfter("not_understood", after=1)
    agent = PolicyAgent(policy)
    assert agent.declared_outcome is None  # before its first action it has not declared
    agent.act({"rgb": np.zeros((16, 16, 3), np.uint8)})
    assert agent.declared_outcome == "not_understood"
    assert agent.reading() == FakeReading().as_dict()
    system = SimpleNamespace(declared_outcome="not_found", reading=FakeReading())
    untrained = UntrainedDualSystemAgent(system)
    assert untrained.declared_outcome == "not_found"
    assert untrained.reading() == FakeReading().as_dict()
    system.declared_outcome, system.reading = None, None
    assert untrained.declared_outcome is None and untrained.reading() is None
