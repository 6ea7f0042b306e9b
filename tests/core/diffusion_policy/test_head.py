"""DiffusionPolicy / L1RegressionHead: seed calls, determinism, validation, bimodal toy."""

import pytest
import torch
import torch.nn.functional as F

from vla_gr.core.diffusion_policy import DiffusionPolicy, L1RegressionHead

H, A = 8, 2


def _modes() -> torch.Tensor:
    """Two context-dependent mode chunks ``(2, H, A)``; actions are +/- the mode."""
    s = torch.linspace(0, 3.14, H)
    m0 = torch.stack([0.7 * torch.ones(H), 0.5 * torch.sin(s)], -1)
    m1 = torch.stack([0.5 * torch.cos(s), -0.6 * torch.ones(H)], -1)
    return torch.stack([m0, m1])


MODES = _modes()


def _batch(n: int, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    c = torch.randint(0, 2, (n,), generator=g)
    sign = (torch.randint(0, 2, (n,), generator=g) * 2 - 1).float()
    return MODES[c] * sign[:, None, None], F.one_hot(c, 2).float()


def _train(policy, steps: int, lr: float = 5e-3):
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    for _ in range(steps):
        actions, ctx = _batch(64, g)
        loss = policy(actions, ctx, generator=g)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    return policy.eval()


def _mode_stats(samples: torch.Tensor, c: torch.Tensor):
    """Fraction of samples within RMS 0.2 of a mode, and per-context fraction of '+'."""
    target = MODES[c]  # (N, H, A)
    d_plus = (samples - target).pow(2).mean((1, 2)).sqrt()
    d_minus = (samples + target).pow(2).mean((1, 2)).sqrt()
    near = (torch.minimum(d_plus, d_minus) < 0.2).float().mean().item()
    plus = [(d_plus < d_minus)[c == k].float().mean().item() for k in (0, 1)]
    return near, plus


EVAL_C = torch.tensor([0] * 100 + [1] * 100)


@pytest.mark.parametrize(
    ("objective", "sampler"), [("flow_matching", "euler"), ("diffusion", "ddim")]
)
def test_generative_heads_learn_both_modes(objective, sampler):
    torch.manual_seed(0)
    policy = DiffusionPolicy(
        A, 32, 2, 50, "v_prediction", objective=objective, horizon=H, denoiser="transformer",
        num_layers=2,
    )  # fmt: skip
    _train(policy, 600)
    gen = torch.Generator().manual_seed(1)
    x = policy.get_action(F.one_hot(EVAL_C, 2).float(), 10, sampler=sampler, generator=gen)
    near, plus = _mode_stats(x, EVAL_C)
    assert near > 0.7, near  # samples land on a mode, not between them
    for frac in plus:  # and both modes are represented for each context
        assert 0.2 < frac < 0.8, plus


def test_l1_head_averages_the_modes():
    torch.manual_seed(0)
    policy = DiffusionPolicy(A, 32, 2, objective="l1", horizon=H, num_layers=1)
    _train(policy, 300)
    x = policy.get_action(F.one_hot(EVAL_C, 2).float())
    near, _ = _mode_stats(x, EVAL_C)
    mode_rms = MODES.pow(2).mean().sqrt().item()  # ~0.5
    assert near == 0.0
    assert x.pow(2).mean().sqrt().item() < 0.4 * mode_rms  # ~0: between the two modes


def test_seed_calls_as_written():
    torch.manual_seed(0)
    policy = DiffusionPolicy(7, 64, 32, 100, "v_prediction")
    actions = torch.rand(3, 16, 7) * 2 - 1
    context = torch.randn(3, 32)
    out = policy(actions, context)
    assert out["loss"].dim() == 0 and out["loss"].requires_grad
    out["loss"].backward()
    chunk = policy.get_action(context, num_inference_steps=10)
    assert chunk.shape == (3, 16, 7)
    assert chunk.abs().max() <= 1.0
    assert DiffusionPolicy(7, 64).context_dim == 64  # context_dim defaults to hidden_dim


@pytest.mark.parametrize("objective", ["diffusion", "flow_matching", "l1"])
@pytest.mark.parametrize("denoiser", ["unet1d", "transformer"])
@pytest.mark.parametrize("horizon", [8, 12, 32])
def test_shapes_for_horizons_and_token_contexts(objective, denoiser, horizon):
    policy = DiffusionPolicy(
        3, 32, 16, 20, "epsilon", objective=objective, horizon=horizon, denoiser=denoiser,
        num_layers=1,
    )  # fmt: skip
    ctx = torch.randn(2, 5, 16)
    pad = torch.tensor([[False] * 5, [False, False, False, True, True]])
    loss = policy(torch.zeros(2, horizon, 3), ctx, context_padding_mask=pad)["loss"]
    assert torch.isfinite(loss)
    assert policy.get_action(ctx, 3, context_padding_mask=pad).shape == (2, horizon, 3)


@pytest.mark.parametrize(
    ("objective", "sampler"),
    [("diffusion", "ddim"), ("diffusion", "ddpm"), ("flow_matching", "euler"),
     ("flow_matching", "midpoint")],
)  # fmt: skip
def test_sampling_is_deterministic_under_a_seed(objective, sampler):
    policy = DiffusionPolicy(2, 32, 4, 30, objective=objective, horizon=8).eval()
    ctx = torch.randn(3, 4)

    def sample(seed):
        gen = torch.Generator().manual_seed(seed)
        return policy.get_action(ctx, 5, sampler=sampler, generator=gen)

    assert torch.equal(sample(7), sample(7))
    assert not torch.equal(sample(7), sample(8))


def test_ddim_eta_zero_is_a_deterministic_map_of_the_noise():
    policy = DiffusionPolicy(2, 32, 4, 30, horizon=8).eval()
    ctx, noise = torch.randn(2, 4), torch.randn(2, 8, 2)
    a = policy.get_action(ctx, 10, sampler="ddim", noise=noise, generator=torch.Generator())
    b = policy.get_action(ctx, 10, sampler="ddim", noise=noise, generator=torch.Generator())
    assert torch.equal(a, b)  # no randomness beyond the initial noise
    c = policy.get_action(ctx, 10, sampler="ddim", noise=noise, eta=1.0)
    assert not torch.allclose(a, c)


def test_flow_sampler_matches_reference_integration():
    from vla_gr.core.diffusion_policy import FLOW_TIME_SCALE
    from vla_gr.core.diffusion_policy.flow_matching import integrate_flow

    policy = DiffusionPolicy(2, 32, 4, objective="flow_matching", horizon=8, clip_sample=False)
    policy.eval()
    ctx, noise = torch.randn(2, 1, 4), torch.randn(2, 8, 2)

    def field(x, t):
        return policy.denoiser(x, (t * FLOW_TIME_SCALE).expand(x.shape[0]), ctx)

    with torch.no_grad():
        for method in ("euler", "midpoint"):
            ref = integrate_flow(field, noise, 4, method)
            out = policy.get_action(ctx, 4, sampler=method, noise=noise)
            assert torch.allclose(out, ref, atol=1e-5), method


def test_forward_loss_reproducible_with_generator():
    policy = DiffusionPolicy(2, 32, 4, 30, horizon=8)
    acts, ctx = torch.rand(4, 8, 2), torch.randn(4, 4)
    l1 = policy(acts, ctx, generator=torch.Generator().manual_seed(0))["loss"]
    l2 = policy(acts, ctx, generator=torch.Generator().manual_seed(0))["loss"]
    assert torch.equal(l1, l2)


def test_bad_arguments_name_the_valid_choices():
    with pytest.raises(ValueError, match=r"prediction_type.*epsilon"):
        DiffusionPolicy(7, 32, prediction_type="x0")
    with pytest.raises(ValueError, match=r"objective.*flow_matching"):
        DiffusionPolicy(7, 32, objective="gan")
    with pytest.raises(ValueError, match=r"denoiser.*unet1d"):
        DiffusionPolicy(7, 32, denoiser="mlp")
    policy = DiffusionPolicy(2, 32, 4, horizon=8)
    with pytest.raises(ValueError, match=r"sampler.*ddim"):
        policy.get_action(torch.randn(1, 4), sampler="euler")
    flow = DiffusionPolicy(2, 32, 4, objective="flow_matching", horizon=8)
    with pytest.raises(ValueError, match=r"sampler.*midpoint"):
        flow.get_action(torch.randn(1, 4), sampler="ddim")
    with pytest.raises(ValueError, match="actions"):
        policy(torch.zeros(1, 9, 2), torch.randn(1, 4))
    with pytest.raises(ValueError, match="context"):
        policy(torch.zeros(1, 8, 2), torch.randn(1, 5))
    with pytest.raises(ValueError, match="num_inference_steps"):
        policy.get_action(torch.randn(1, 4), num_inference_steps=0)
    with pytest.raises(ValueError, match="horizon"):
        L1RegressionHead(2, 32, horizon=0)


def test_gradient_checkpointing_matches_plain_gradients():
    for den in ("unet1d", "transformer"):
        torch.manual_seed(0)
        policy = DiffusionPolicy(2, 32, 4, 30, horizon=8, denoiser=den, num_layers=1)
        acts, ctx = torch.rand(3, 8, 2), torch.randn(3, 4)
        policy(acts, ctx, generator=torch.Generator().manual_seed(0))["loss"].backward()
        ref = [p.grad.clone() for p in policy.parameters()]
        policy.zero_grad()
        policy.denoiser.gradient_checkpointing = True
        policy(acts, ctx, generator=torch.Generator().manual_seed(0))["loss"].backward()
        for r, p in zip(ref, policy.parameters()):
            assert torch.allclose(r, p.grad, atol=1e-5), den


def test_get_action_returns_an_ordinary_tensor():
    policy = DiffusionPolicy(2, 32, 4, objective="flow_matching", horizon=8).eval()
    out = policy.get_action(torch.randn(1, 4), 2)
    assert not out.is_inference()
    w = torch.ones(2, requires_grad=True)
    (out * w).sum().backward()  # usable in later autograd code
    assert w.grad is not None


def test_default_unet_widths_follow_hidden_dim():
    policy = DiffusionPolicy(7, 128, objective="flow_matching")
    assert policy.denoiser.down_dims == (32, 64, 128)
    assert DiffusionPolicy(7, 36, n_groups=4).denoiser.down_dims == (8, 16, 36)
    custom = DiffusionPolicy(7, 64, down_dims=(16, 32), horizon=10)
    assert custom.denoiser.down_dims == (16, 32)
    assert custom.get_action(torch.randn(2, 64), 2).shape == (2, 10, 7)


@pytest.mark.slow
def test_compiled_sampler_matches_eager():
    policy = DiffusionPolicy(2, 32, 4, objective="flow_matching", horizon=8).eval()
    ctx, noise = torch.randn(1, 4), torch.randn(1, 8, 2)
    eager = policy.get_action(ctx, 3, noise=noise)
    policy.compile_sampler()
    assert torch.allclose(policy.get_action(ctx, 3, noise=noise), eager, atol=1e-5)
