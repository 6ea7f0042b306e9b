"""Dual system: planning schedule, gating, trained confidence, threaded runner."""

from __future__ import annotations

import statistics
import time

import pytest
import torch
from torch import nn

from vla_gr.core.dual_system import (
    DualSystemArchitecture,
    confidence_targets,
    gate_actions,
    plan_interval,
)
from vla_gr.core.dual_system.runner import DualSystemRunner, LatestSlot


def small_model(**kw) -> DualSystemArchitecture:
    torch.manual_seed(0)
    args = dict(
        visual_dim=16,
        vlm_dim=12,
        s1_hidden_dim=32,
        s2_hidden_dim=32,
        planning_frequency_hz=2.0,
        control_frequency_hz=10.0,
        s2_num_heads=4,
    )
    args.update(kw)
    return DualSystemArchitecture(**args)


def test_seed_call_and_default_sizes():
    model = DualSystemArchitecture(
        visual_dim=512,
        vlm_dim=768,
        s1_hidden_dim=256,
        s2_hidden_dim=512,
        planning_frequency_hz=2.0,
        control_frequency_hz=20.0,
    ).eval()
    out = model(
        visual_features=torch.randn(2, 512),
        vlm_features=torch.randn(2, 5, 768),
        proprioception=torch.randn(2, 7),
    )
    assert out["action"].shape == (2, 7)
    assert out["latent_goal"].shape == (2, 256)
    assert out["subgoals"].shape == (2, 4, 256)
    assert out["s2_ran"] is True
    assert ((out["confidence"] > 0) & (out["confidence"] < 1)).all()
    # S1 is the fast system: <= 2 M parameters at the defaults.
    assert sum(p.numel() for p in model.s1.parameters()) <= 2_000_000
    assert DualSystemArchitecture().num_parameters()["s1"] <= 2_000_000


@pytest.mark.parametrize(("control", "planning", "expected"), [(10, 2, 5), (20, 3, 7), (5, 5, 1)])
def test_plan_interval(control, planning, expected):
    assert plan_interval(control, planning) == expected


def test_plan_interval_rejects_bad_rates():
    with pytest.raises(ValueError, match="planning_frequency_hz"):
        plan_interval(10.0, 20.0)
    with pytest.raises(ValueError, match="control_frequency_hz"):
        plan_interval(0.0, 1.0)


@pytest.mark.parametrize(("control", "planning", "steps"), [(10.0, 2.0, 23), (30.0, 3.0, 40)])
def test_s2_call_count_matches_frequency_ratio(control, planning, steps):
    model = small_model(control_frequency_hz=control, planning_frequency_hz=planning).eval()
    k = plan_interval(control, planning)
    vis, vlm, prop = torch.randn(3, 16), torch.randn(3, 4, 12), torch.randn(3, 7)
    ran = []
    with torch.no_grad():
        for _ in range(steps):
            ran.append(model(visual_features=vis, vlm_features=vlm, proprioception=prop)["s2_ran"])
    assert sum(ran) == model.s2_calls == -(-steps // k)  # ceil(steps / k)
    assert [i for i, r in enumerate(ran) if r] == list(range(0, steps, k))


def test_cache_reset_and_force_plan():
    model = small_model().eval()
    vis, prop = torch.randn(2, 16), torch.randn(2, 7)
    vlm_a, vlm_b = torch.randn(2, 3, 12), torch.randn(2, 3, 12)
    with torch.no_grad():
        first = model(visual_features=vis, vlm_features=vlm_a, proprioception=prop)
        # Between planning ticks the cached goal is used: new VLM input is ignored.
        second = model(visual_features=vis, vlm_features=vlm_b, proprioception=prop)
        assert not second["s2_ran"]
        torch.testing.assert_close(second["latent_goal"], first["latent_goal"])
        torch.testing.assert_close(second["action"], first["action"])
        forced = model(
            visual_features=vis, vlm_features=vlm_b, proprioception=prop, force_plan=True
        )
        assert forced["s2_ran"]
        assert not torch.allclose(forced["latent_goal"], first["latent_goal"])
        model.reset()
        assert model(visual_features=vis, vlm_features=vlm_a, proprioception=prop)["s2_ran"]
        # A new batch size invalidates the per-batch cache.
        out = model(visual_features=vis[:1], vlm_features=vlm_a[:1], proprioception=prop[:1])
        assert out["s2_ran"]


def test_training_mode_runs_s2_every_call_with_gradients():
    model = small_model().train()
    vis, vlm, prop = torch.randn(2, 16), torch.randn(2, 3, 12), torch.randn(2, 7)
    for _ in range(3):
        out = model(visual_features=vis, vlm_features=vlm, proprioception=prop)
        assert out["s2_ran"]
    out["action"].sum().backward()
    assert model.s2.goal_head.weight.grad is not None
    assert model.s2.goal_head.weight.grad.abs().sum() > 0


def test_gate_actions_is_convex_blend():
    goal, reactive = torch.tensor([[1.0, 2.0]]), torch.tensor([[3.0, -2.0]])
    torch.testing.assert_close(gate_actions(goal, reactive, torch.tensor([1.0])), goal)
    torch.testing.assert_close(gate_actions(goal, reactive, torch.tensor([0.0])), reactive)
    torch.testing.assert_close(
        gate_actions(goal, reactive, torch.tensor([0.25])), torch.tensor([[2.5, -1.0]])
    )


def test_zero_confidence_gives_reactive_action_exactly():
    model = small_model().eval()
    vis, prop = torch.randn(2, 16), torch.randn(2, 7)
    goal = torch.randn(2, model.goal_dim)
    with torch.no_grad():
        out = model.act(vis, prop, goal, torch.zeros(2))
        other = model.act(vis, prop, 5 * torch.randn(2, model.goal_dim), torch.zeros(2))
    torch.testing.assert_close(out["action"], out["reactive_action"])
    torch.testing.assert_close(out["action"], other["action"])  # goal is ignored at c = 0


def test_confidence_targets():
    t = confidence_targets(torch.tensor([0.1, 0.5, 0.3]), torch.tensor([0.2, 0.4, 0.3]))
    torch.testing.assert_close(t, torch.tensor([1.0, 0.0, 0.0]))


@pytest.mark.parametrize("gate", ["confidence", "learned"])
def test_confidence_is_trained_towards_useful_goals(gate):
    """Targets depend only on the VLM input: the goal branch wins, confidence rises."""
    torch.manual_seed(0)
    model = small_model(gate=gate).train()
    w = torch.randn(12, 7)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)

    def batch():
        vlm = torch.randn(64, 12)
        return torch.randn(64, 16), vlm, torch.randn(64, 7), torch.tanh(vlm @ w)

    with torch.no_grad():
        c0 = model.compute_loss(*batch())["confidence_mean"].item()
    grads_seen = False
    for _ in range(150):
        losses = model.compute_loss(*batch(), confidence_weight=1.0)
        opt.zero_grad()
        losses["loss"].backward()
        grads_seen |= model.s2.confidence_head.weight.grad.abs().sum().item() > 0
        opt.step()
    with torch.no_grad():
        final = model.compute_loss(*batch())
    assert grads_seen
    assert final["confidence_target_mean"] > 0.8  # the goal branch is better on most samples
    assert final["confidence_mean"] > max(0.8, c0 + 0.2)
    assert final["action_loss"] < 0.5 * torch.tanh(torch.randn(256, 12) @ w).pow(2).mean()


def test_bad_inputs_raise_clearly():
    model = small_model()
    with pytest.raises(ValueError, match="visual_features"):
        model(visual_features=torch.randn(2, 15), vlm_features=torch.randn(2, 12))
    with pytest.raises(ValueError, match="vlm_features"):
        model(visual_features=torch.randn(2, 16), vlm_features=torch.randn(2, 11))
    with pytest.raises(ValueError, match="proprioception"):
        model(
            visual_features=torch.randn(2, 16),
            vlm_features=torch.randn(2, 12),
            proprioception=torch.randn(2, 3),
        )
    with pytest.raises(ValueError, match="target_actions"):
        model.compute_loss(torch.randn(2, 16), torch.randn(2, 12), None, torch.randn(2, 6))
    with pytest.raises(ValueError, match="gate"):
        small_model(gate="max")
    with pytest.raises(ValueError, match="s2_hidden_dim"):
        small_model(s2_hidden_dim=30)


# ------------------------------------------------------------------ threaded runner


class _SlowPlanner(nn.Module):
    """Wraps S2 and sleeps before planning (a deliberately slow VLM)."""

    def __init__(self, inner: nn.Module, delay_s: float, fail: bool = False) -> None:
        super().__init__()
        self.inner, self.delay_s, self.fail = inner, delay_s, fail

    def forward(self, *args, **kwargs):
        time.sleep(self.delay_s)
        if self.fail:
            raise FloatingPointError("planner exploded")
        return self.inner(*args, **kwargs)


def _median_step_ms(runner: DualSystemRunner, n: int, vis, prop) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        runner.step(vis, prop)
        times.append(time.perf_counter() - t0)
        time.sleep(0.002)
    return 1e3 * statistics.median(times)


def test_latest_slot_versions():
    slot = LatestSlot()
    assert slot.get() == (None, 0)
    slot.put("a")
    slot.put("b")
    assert slot.get() == ("b", 2)


def test_slow_s2_does_not_raise_s1_latency_and_runs_at_its_rate():
    model = small_model(planning_frequency_hz=4.0, control_frequency_hz=20.0)
    vis, prop, vlm = torch.randn(1, 16), torch.randn(1, 7), torch.randn(1, 6, 12)
    # Baseline: S1 steps with no planner thread at all.
    baseline = DualSystemRunner(model)
    base_ms = _median_step_ms(baseline, 60, vis, prop)

    model.s2 = _SlowPlanner(model.s2, delay_s=0.2)
    with DualSystemRunner(model, planning_frequency_hz=4.0) as runner:
        runner.set_planner_input(vlm)
        runner.wait_for_plan(timeout_s=5.0)
        t0 = time.perf_counter()
        slow_ms = _median_step_ms(runner, 250, vis, prop)
        out = runner.step(vis, prop)
        elapsed = time.perf_counter() - t0
        n_plans = len(runner.plan_times)
    assert out["plan_index"] >= 1
    # A blocking S1 would wait ~200 ms per step; the margin is huge on purpose.
    assert slow_ms < 3.0 * base_ms + 5.0, (slow_ms, base_ms)
    # S2 takes 200 ms per plan, so it cannot exceed 1 / 0.2 s = 5 Hz; target is 4 Hz.
    expected = 4.0 * elapsed
    assert 0.4 * expected <= n_plans - 1 <= 5.0 * elapsed + 1.5, (n_plans, elapsed)


def test_threaded_s2_runs_at_configured_rate():
    model = small_model()
    with DualSystemRunner(model, planning_frequency_hz=10.0) as runner:
        runner.set_planner_input(torch.randn(1, 4, 12))
        runner.wait_for_plan(timeout_s=5.0)
        time.sleep(1.5)
        rate = runner.measured_rate_hz()
        n = len(runner.plan_times)
    assert 5.0 <= rate <= 12.0, rate  # rate-limited, not free-running
    assert n <= 1.5 * 10 + 4


def test_runner_reactive_before_first_plan_and_plan_used_after():
    model = small_model()
    vis, prop, vlm = torch.randn(1, 16), torch.randn(1, 7), torch.randn(1, 4, 12)
    runner = DualSystemRunner(model, planning_frequency_hz=20.0)
    out = runner.step(vis, prop)  # not started: no plan, purely reactive
    assert out["plan_index"] == 0
    torch.testing.assert_close(out["action"], out["reactive_action"])
    with runner:
        runner.set_planner_input(vlm)
        plan = runner.wait_for_plan()
        out = runner.step(vis, prop)
    with torch.no_grad():
        ref = model.plan(vlm)
        expected = model.act(vis, prop, ref["latent_goal"], ref["confidence"])["action"]
    assert out["plan_index"] >= plan.index
    torch.testing.assert_close(out["action"], expected)
    assert not runner.running


def test_runner_surfaces_planner_exceptions():
    model = small_model()
    model.s2 = _SlowPlanner(model.s2, delay_s=0.0, fail=True)
    runner = DualSystemRunner(model).start()
    runner.set_planner_input(torch.randn(1, 4, 12))
    deadline = time.perf_counter() + 5.0
    with pytest.raises(RuntimeError, match="planner exploded"):  # noqa: PT012
        while time.perf_counter() < deadline:
            runner.step(torch.randn(1, 16), torch.randn(1, 7))
            time.sleep(0.01)
    runner.stop()  # already surfaced: does not raise again
    assert not runner.running


def test_subgoal_loss_and_shape_check():
    model = small_model(num_subgoals=3).train()
    args = (torch.randn(4, 16), torch.randn(4, 5, 12), torch.randn(4, 7), torch.randn(4, 7))
    out = model.compute_loss(*args, subgoal_targets=torch.zeros(4, 3, model.goal_dim))
    without = model.compute_loss(*args)
    assert out["subgoal_loss"] > 0
    torch.testing.assert_close(out["loss"] - out["subgoal_loss"], without["loss"])
    with pytest.raises(ValueError, match="subgoal_targets"):
        model.compute_loss(*args, subgoal_targets=torch.zeros(4, 2, model.goal_dim))


def test_runner_reset_forgets_the_plan():
    model = small_model()
    with DualSystemRunner(model, planning_frequency_hz=20.0) as runner:
        runner.set_planner_input(torch.randn(1, 4, 12))
        runner.wait_for_plan()
        runner.reset()
        out = runner.step(torch.randn(1, 16), torch.randn(1, 7))
    assert out["plan_index"] == 0


def test_runner_reset_drops_a_plan_in_flight():
    model = small_model()
    model.s2 = _SlowPlanner(model.s2, delay_s=0.3)
    with DualSystemRunner(model, planning_frequency_hz=2.0) as runner:
        runner.set_planner_input(torch.randn(1, 4, 12))
        time.sleep(0.1)  # the planner is now inside its 300 ms call
        runner.reset()
        time.sleep(0.4)  # ... and has finished it
        assert runner.latest_plan() is None
        assert runner.plan_times == []
