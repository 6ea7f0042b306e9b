"""Denoisers: fast conv paths and the batch-1 step plan equal PyTorch's / the reference."""

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.core.diffusion_policy import DiffusionPolicy
from vla_gr.core.diffusion_policy.denoisers import (
    ConditionalUnet1D,
    FastConv1d,
    FastConvTranspose1d,
    TransformerDenoiser,
    masked_mean,
    sinusoidal_embedding,
)
from vla_gr.core.diffusion_policy.unet_inference import (
    UnetStepPlan,
    conv_selection,
    conv_transpose_selection,
)
from vla_gr.core.peft_modules import apply_lora_to_model, merge_peft


@pytest.mark.parametrize(("k", "stride", "pad"), [(5, 1, 2), (3, 2, 1), (1, 1, 0)])
@pytest.mark.parametrize("length", [4, 7, 16])
def test_fast_conv1d_equals_conv1d(k, stride, pad, length):
    torch.manual_seed(0)
    fast = FastConv1d(96, 128, k, stride, pad)  # >= 10k weights: matmul path
    ref = nn.Conv1d(96, 128, k, stride, pad)
    ref.load_state_dict(fast.state_dict())
    x = torch.randn(1, 96, length, requires_grad=True)
    y = fast(x)  # matmul path (small batch)
    assert torch.allclose(y, ref(x), atol=1e-4)
    y.sum().backward()  # differentiable
    assert x.grad is not None
    big = torch.randn(64, 96, length)  # large batch falls back to nn.Conv1d
    assert torch.allclose(fast(big), ref(big), atol=1e-4)


@pytest.mark.parametrize("length", [2, 4, 8])
def test_fast_conv_transpose_equals_conv_transpose(length):
    torch.manual_seed(0)
    fast = FastConvTranspose1d(16, 12, 4, 2, 1)
    ref = nn.ConvTranspose1d(16, 12, 4, 2, 1)
    ref.load_state_dict(fast.state_dict())
    x = torch.randn(2, 16, length)
    assert fast(x).shape == (2, 12, 2 * length)
    assert torch.allclose(fast(x), ref(x), atol=1e-5)


def test_sinusoidal_embedding_and_masked_mean():
    emb = sinusoidal_embedding(torch.tensor([0.0, 3.0]), 8)
    assert torch.allclose(emb[0], torch.tensor([0.0] * 4 + [1.0] * 4))
    assert emb[1, 0].item() == pytest.approx(torch.sin(torch.tensor(3.0)).item())
    tok = torch.tensor([[[1.0], [3.0], [100.0]]])
    assert masked_mean(tok, torch.tensor([[False, False, True]])).item() == pytest.approx(2.0)


@pytest.mark.parametrize("kind", ["unet1d", "transformer"])
@pytest.mark.parametrize("horizon", [8, 10, 16])
def test_step_conditions_equal_forward(kind, horizon):
    torch.manual_seed(0)
    if kind == "unet1d":
        net = ConditionalUnet1D(3, 12, (16, 32, 64), time_embed_dim=16).eval()
    else:
        net = TransformerDenoiser(3, 12, 32, num_layers=2).eval()
    x = torch.randn(2, horizon, 3)
    ctx = torch.randn(2, 4, 12)
    pad = torch.tensor([[False] * 4, [False, True, True, True]])
    ts = torch.tensor([90.0, 40.0, 3.0])
    with torch.no_grad():
        prepared = net.prepare_context(ctx, pad)
        conds = net.step_conditions(net.embed_time(ts), prepared)
        for i, t in enumerate(ts):
            ref = net(x, t.expand(2), ctx, pad)
            assert ref.shape == (2, horizon, 3)
            assert torch.allclose(net.denoise_step(x, conds[i]), ref, atol=1e-5)


def test_step_conditions_with_a_lora_film_encoder_equal_forward():
    torch.manual_seed(0)
    net = ConditionalUnet1D(3, 12, (16, 32), time_embed_dim=16).eval()
    apply_lora_to_model(net, ["downs.0.0.cond_encoder.1"], rank=2)  # not a plain Linear
    with torch.no_grad():
        for name, p in net.named_parameters():
            if "lora_B" in name:
                p.normal_(0.0, 0.1)
        x, ctx, t = torch.randn(1, 8, 3), torch.randn(1, 2, 12), torch.tensor([70.0])
        conds = net.step_conditions(net.embed_time(t), net.prepare_context(ctx))
        ref = net(x, t, ctx)
        assert torch.allclose(net.denoise_step(x, conds[0]), ref, atol=1e-5)
        net.downs[0][0].cond_encoder[1].lora_B["default"].weight.zero_()  # LoRA mattered
        assert not torch.allclose(net(x, t, ctx), ref, atol=1e-4)


def test_unet_output_depends_on_time_and_context():
    torch.manual_seed(0)
    net = ConditionalUnet1D(2, 4, (8, 16), time_embed_dim=8).eval()
    x, ctx = torch.randn(1, 8, 2), torch.randn(1, 1, 4)
    with torch.no_grad():
        a = net(x, torch.tensor([1.0]), ctx)
        b = net(x, torch.tensor([50.0]), ctx)
        c = net(x, torch.tensor([1.0]), ctx + 1.0)
    assert not torch.allclose(a, b, atol=1e-4)  # the timestep conditions the output
    assert not torch.allclose(a, c, atol=1e-4)  # so does the context


def test_unet_rejects_bad_dims():
    with pytest.raises(ValueError, match="down_dims"):
        ConditionalUnet1D(2, 4, (12, 16), n_groups=8)
    with pytest.raises(ValueError, match="kernel_size"):
        ConditionalUnet1D(2, 4, (8, 16), kernel_size=4)


# ---------------------------------------------------------------- batch-1 step plan


@pytest.mark.parametrize(
    ("k", "stride", "pad", "length"), [(5, 1, 2, 8), (3, 2, 1, 7), (1, 1, 0, 4)]
)
def test_conv_selection_is_im2col(k, stride, pad, length):
    x = torch.randn(3, length)
    cols = (x @ conv_selection(length, k, stride, pad, x)).view(3, k, -1)  # (C, k, Lo)
    ref = F.pad(x, (pad, pad)).unfold(1, k, stride).transpose(1, 2)  # (C, k, Lo)
    assert torch.equal(cols, ref)


def test_conv_transpose_selection_scatters_like_conv_transpose():
    torch.manual_seed(0)
    conv = nn.ConvTranspose1d(1, 1, 4, 2, 1, bias=False)
    x = torch.randn(1, 1, 5)
    taps = (x[0, 0, :, None] * conv.weight[0, 0]).reshape(-1)  # (L*k,) in (i, j) order
    out = conv_transpose_selection(5, 4, 2, 1, x) @ taps  # (Lo,)
    assert torch.allclose(out, conv(x)[0, 0], atol=1e-6)


def _reference_step(net, x, films):
    return ConditionalUnet1D.denoise_step(net, x, films)


@pytest.mark.parametrize(
    ("dims", "kernel", "horizon"),
    [((16, 32, 64), 5, 16), ((16, 32, 64), 5, 10), ((8, 16), 3, 8), ((16, 32, 64), 3, 31)],
)
def test_step_plan_equals_reference_step(dims, kernel, horizon):
    torch.manual_seed(0)
    net = ConditionalUnet1D(3, 12, dims, time_embed_dim=16, kernel_size=kernel).eval()
    x, ctx = torch.randn(1, horizon, 3), torch.randn(1, 4, 12)
    with torch.no_grad():
        conds = net.step_conditions(
            net.embed_time(torch.tensor([900.0, 3.0])), {"global": ctx.mean(1)}
        )
        plan = net.sampling_step(x)
        assert isinstance(plan, UnetStepPlan)
        for films in conds:
            out = plan(x, films)
            assert out.shape == (1, horizon, 3)
            assert torch.allclose(out, _reference_step(net, x, films), atol=1e-5)


def test_step_plan_only_for_batch_one_and_known_modules():
    net = ConditionalUnet1D(3, 12, (16, 32), time_embed_dim=16)
    assert net.sampling_step(torch.randn(2, 8, 3)) == net.denoise_step  # batch 2: reference
    assert isinstance(net.sampling_step(torch.randn(1, 8, 3)), UnetStepPlan)
    apply_lora_to_model(net, ["downs.0.0.block1.0"], rank=2)  # an unmerged LoRA conv
    assert net.sampling_step(torch.randn(1, 8, 3)) == net.denoise_step


def _flow_policy(**kw) -> DiffusionPolicy:
    torch.manual_seed(0)
    return DiffusionPolicy(3, 64, 8, objective="flow_matching", horizon=16, **kw).eval()


def _reference_action(policy, ctx, noise, steps=4, sampler="euler"):
    """``get_action`` through the reference ``denoise_step`` (no step plan)."""
    den = policy.denoiser
    den.sampling_step = lambda x: den.denoise_step
    try:
        return policy.get_action(ctx, steps, sampler=sampler, noise=noise)
    finally:
        del den.sampling_step


@pytest.mark.parametrize("sampler", ["euler", "midpoint"])
def test_policy_fast_path_equals_reference(sampler):
    policy = _flow_policy()
    ctx, noise = torch.randn(1, 8), torch.randn(1, 16, 3)
    fast = policy.get_action(ctx, 4, sampler=sampler, noise=noise)
    assert torch.allclose(fast, _reference_action(policy, ctx, noise, 4, sampler), atol=1e-5)


def test_ddim_fast_path_equals_reference():
    torch.manual_seed(0)
    policy = DiffusionPolicy(3, 64, 8, 50, "epsilon", horizon=16, clip_sample=False).eval()
    ctx, noise = torch.randn(1, 8), torch.randn(1, 16, 3)
    fast = policy.get_action(ctx, 5, noise=noise)
    assert torch.allclose(fast, _reference_action(policy, ctx, noise, 5, "ddim"), atol=1e-4)


def test_fast_path_follows_optimizer_steps_and_replaced_weights():
    policy = _flow_policy(clip_sample=False)
    ctx, noise = torch.randn(1, 8), torch.randn(1, 16, 3)
    before = policy.get_action(ctx, 3, noise=noise)
    stale_plan = policy.denoiser.sampling_step(noise)  # built before the update
    opt = torch.optim.SGD(policy.parameters(), lr=0.5)
    policy.train()
    policy(torch.rand(4, 16, 3) * 2 - 1, torch.randn(4, 8))["loss"].backward()
    opt.step()
    policy.eval()
    after = policy.get_action(ctx, 3, noise=noise)
    assert not torch.allclose(before, after, atol=1e-3)  # the weights moved ...
    assert torch.allclose(after, _reference_action(policy, ctx, noise, 3), atol=1e-5)  # ... seen
    den = policy.denoiser
    with torch.no_grad():  # even a plan built earlier holds views, not copies
        films = den.step_conditions(den.embed_time(torch.tensor([500.0])), {"global": ctx})[0]
        assert torch.allclose(stale_plan(noise, films), den.denoise_step(noise, films), atol=1e-5)
    with torch.no_grad():  # replaced parameter storage: the next chunk builds a new plan
        for p in den.parameters():
            p.data = p.data * 1.5
    replaced = policy.get_action(ctx, 3, noise=noise)
    assert not torch.allclose(replaced, after, atol=1e-3)
    assert torch.allclose(replaced, _reference_action(policy, ctx, noise, 3), atol=1e-5)


def test_fast_path_with_lora_unmerged_and_merged():
    policy = _flow_policy(clip_sample=False)
    ctx, noise = torch.randn(1, 8), torch.randn(1, 16, 3)
    targets = ["downs.0.0.block1.0", "mids.0.block2.0", "ups.0.0.residual", "mids.1.cond_encoder.1"]
    apply_lora_to_model(policy.denoiser, targets, rank=4)
    with torch.no_grad():
        for name, p in policy.named_parameters():
            if "lora_B" in name:
                p.normal_(0.0, 0.05)
    unmerged = policy.get_action(ctx, 3, noise=noise)  # reference path (wrapped convs)
    assert torch.allclose(unmerged, _reference_action(policy, ctx, noise, 3), atol=1e-5)
    merge_peft(policy.denoiser)
    assert isinstance(policy.denoiser.sampling_step(noise), UnetStepPlan)
    merged = policy.get_action(ctx, 3, noise=noise)  # step plan on the merged weights
    assert torch.allclose(merged, unmerged, atol=1e-4)
