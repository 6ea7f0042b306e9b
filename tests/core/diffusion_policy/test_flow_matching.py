"""Flow-matching and diffusion-target maths against closed forms."""

import math

import pytest
import torch
from diffusers import DDIMScheduler, DDPMScheduler

from vla_gr.core.diffusion_policy.flow_matching import (
    euler_step,
    flow_interpolate,
    flow_target,
    flow_time_grid,
    flow_x0_from_velocity,
    integrate_flow,
    midpoint_step,
    sample_flow_time,
)
from vla_gr.core.diffusion_policy.noise_targets import diffusion_target, predicted_x0, q_sample


def _known():
    x0 = torch.tensor([[[0.5, -1.0], [0.25, 0.0]]])  # (1, 2, 2)
    eps = torch.tensor([[[1.0, 2.0], [-3.0, 0.5]]])  # (1, 2, 2)
    return x0, eps


def test_flow_interpolation_and_target_closed_form():
    x0, eps = _known()
    t = torch.tensor([0.25])
    xt = flow_interpolate(x0, eps, t)
    assert torch.allclose(xt, 0.25 * eps + 0.75 * x0)
    assert torch.allclose(flow_interpolate(x0, eps, torch.zeros(1)), x0)
    assert torch.allclose(flow_interpolate(x0, eps, torch.ones(1)), eps)
    u = flow_target(x0, eps)
    assert torch.allclose(u, eps - x0)
    # u is the time derivative of the path (finite difference is exact for a line).
    h = 1e-2
    fd = (flow_interpolate(x0, eps, t + h) - flow_interpolate(x0, eps, t - h)) / (2 * h)
    assert torch.allclose(fd, u, atol=1e-5)
    assert torch.allclose(flow_x0_from_velocity(xt, u, t), x0, atol=1e-6)


def test_flow_time_distribution_matches_beta_1p5():
    g = torch.Generator().manual_seed(0)
    t = sample_flow_time(200_000, alpha=1.5, s=0.999, generator=g)
    assert t.min() >= 0.001 - 1e-7 and t.max() <= 1.0
    u = (t - 0.001) / 0.999
    # Beta(1.5, 1): mean a/(a+b) = 0.6, CDF u^1.5 -> P(u < 0.5) = 0.3536.
    assert abs(u.mean().item() - 0.6) < 5e-3
    assert abs((u < 0.5).float().mean().item() - 0.5**1.5) < 5e-3
    # Noisy times (t near 1) are emphasised.
    assert (t > 0.5).float().mean() > 0.6
    again = sample_flow_time(10, generator=torch.Generator().manual_seed(3))
    assert torch.equal(again, sample_flow_time(10, generator=torch.Generator().manual_seed(3)))


def test_euler_exact_on_straight_line_field():
    # The optimal field for a single target x0 is v(x, t) = (x - x0) / t; Euler follows
    # its straight trajectories exactly for any step count.
    x0, eps = _known()

    def field(x, t):
        return (x - x0) / t

    for n in (1, 3, 10):
        out = integrate_flow(field, eps, num_steps=n, method="euler")
        assert torch.allclose(out, x0, atol=1e-5), n


def test_midpoint_exact_on_time_linear_field_where_euler_is_not():
    # dx/dt = a + b t integrated from t=1 to 0: x(0) = x(1) - a - b/2.
    a, b = torch.tensor(0.3), torch.tensor(2.0)
    x1 = torch.ones(1, 1, 1)

    def field(x, t):
        return (a + b * t).expand_as(x)

    exact = x1 - a - b / 2
    mid = integrate_flow(field, x1, num_steps=2, method="midpoint")
    eul = integrate_flow(field, x1, num_steps=2, method="euler")
    assert torch.allclose(mid, exact, atol=1e-6)
    assert not torch.allclose(eul, exact, atol=1e-2)
    t, dt = torch.tensor(1.0), torch.tensor(-0.5)
    assert torch.allclose(midpoint_step(x1, t, dt, field), x1 + dt * (a + b * 0.75))
    assert torch.allclose(euler_step(x1, torch.full_like(x1, 2.0), -0.25), x1 - 0.5)


def test_flow_time_grid_and_bad_method():
    assert torch.allclose(flow_time_grid(4), torch.tensor([1.0, 0.75, 0.5, 0.25, 0.0]))
    with pytest.raises(ValueError, match="euler"):
        integrate_flow(lambda x, t: x, torch.zeros(1, 1, 1), 2, method="rk4")
    with pytest.raises(ValueError, match="num_steps"):
        flow_time_grid(0)


def test_diffusion_targets_closed_forms():
    x0, eps = _known()
    acp = torch.tensor([0.9, 0.64, 0.25])
    t = torch.tensor([1])
    ab = 0.64
    xt = q_sample(x0, eps, t, acp)
    assert torch.allclose(xt, 0.8 * x0 + 0.6 * eps)
    v = diffusion_target(x0, eps, t, acp, "v_prediction")
    assert torch.allclose(v, math.sqrt(ab) * eps - math.sqrt(1 - ab) * x0)
    assert torch.allclose(diffusion_target(x0, eps, t, acp, "epsilon"), eps)
    assert torch.allclose(diffusion_target(x0, eps, t, acp, "sample"), x0)
    for pt in ("epsilon", "v_prediction", "sample"):
        target = diffusion_target(x0, eps, t, acp, pt)
        assert torch.allclose(predicted_x0(target, xt, t, acp, pt), x0, atol=1e-6), pt
    with pytest.raises(ValueError, match="v_prediction"):
        diffusion_target(x0, eps, t, acp, "velocity")


def test_targets_agree_with_diffusers_schedulers():
    sched = DDPMScheduler(num_train_timesteps=100, beta_schedule="squaredcos_cap_v2")
    acp = torch.as_tensor(sched.alphas_cumprod)
    g = torch.Generator().manual_seed(0)
    x0 = torch.rand(4, 8, 3, generator=g) * 2 - 1
    eps = torch.randn(4, 8, 3, generator=g)
    t = torch.tensor([0, 10, 57, 99])
    assert torch.allclose(q_sample(x0, eps, t, acp), sched.add_noise(x0, eps, t), atol=1e-6)
    v = diffusion_target(x0, eps, t, acp, "v_prediction")
    assert torch.allclose(v, sched.get_velocity(x0, eps, t), atol=1e-6)
    # With a perfect prediction of each target, a deterministic DDIM step from t to the
    # previous timestep lands exactly on q_sample(x0, eps, t_prev) (x0 after the last).
    for pt in ("epsilon", "v_prediction", "sample"):
        ddim = DDIMScheduler(
            num_train_timesteps=100,
            beta_schedule="squaredcos_cap_v2",
            prediction_type=pt,
            clip_sample=False,
            timestep_spacing="trailing",
        )
        ddim.set_timesteps(10)
        steps = ddim.timesteps.tolist()  # [99, 89, ..., 9]
        for k in range(1, len(steps)):  # skip t=99 where epsilon -> x0 divides by ~0
            tt = torch.full((4,), steps[k])
            xt = q_sample(x0, eps, tt, acp)
            out = ddim.step(diffusion_target(x0, eps, tt, acp, pt), steps[k], xt).prev_sample
            expect = x0 if k == len(steps) - 1 else q_sample(x0, eps, tt - 10, acp)
            assert torch.allclose(out, expect, atol=1e-4), (pt, steps[k])
