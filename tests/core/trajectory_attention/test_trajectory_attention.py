"""RoPE, masked SDPA attention, pre-norm blocks and the TrajectoryEncoder."""

import pytest
import torch

from vla_gr.core.trajectory_attention import (
    MultiHeadAttention,
    TrajectoryEncoder,
    TransformerBlock,
    apply_rope,
    build_attention_mask,
    rope_angles,
)


def test_rope_hand_computed_rotation():
    # D = 4: pair 0 rotates by p * 1, pair 1 by p * base^(-1/2) = p / 100.
    x = torch.tensor([[1.0, 0.0, 1.0, 0.0]])  # (T=1, D=4)
    out = apply_rope(x, torch.tensor([2.0]))
    expect = torch.tensor([[torch.cos(torch.tensor(2.0)), torch.sin(torch.tensor(2.0)), 0, 0]])
    expect[0, 2] = torch.cos(torch.tensor(0.02))
    expect[0, 3] = torch.sin(torch.tensor(0.02))
    assert torch.allclose(out, expect, atol=1e-6)
    cos, sin = rope_angles(torch.arange(5), 8)
    assert cos.shape == (5, 4) and sin.shape == (5, 4)


def test_rope_preserves_norms_and_position_zero_is_identity():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 3, 7, 16, generator=g)  # (B, heads, T, D)
    pos = torch.arange(7) * 3 + 5
    out = apply_rope(x, pos)
    assert out.shape == x.shape
    assert torch.allclose(out.norm(dim=-1), x.norm(dim=-1), atol=1e-5)
    assert torch.allclose(apply_rope(x, torch.zeros(7)), x)


def test_rope_scores_depend_only_on_relative_position():
    g = torch.Generator().manual_seed(1)
    q = torch.randn(1, 1, 1, 32, generator=g)
    k = torch.randn(1, 1, 1, 32, generator=g)

    def score(m, n):
        qm = apply_rope(q, torch.tensor([float(m)]))
        kn = apply_rope(k, torch.tensor([float(n)]))
        return (qm * kn).sum().item()

    base = score(3, 1)
    for shift in (1, 7, 100):
        assert score(3 + shift, 1 + shift) == pytest.approx(base, abs=1e-4)
    assert abs(score(5, 1) - base) > 1e-3  # a different offset gives a different score


def test_rope_batched_positions_match_per_sample():
    g = torch.Generator().manual_seed(2)
    x = torch.randn(2, 4, 5, 8, generator=g)  # (B, h, T, d)
    pos = torch.tensor([[0, 1, 2, 3, 4], [10, 11, 12, 13, 14]])
    out = apply_rope(x, pos)
    for b in range(2):
        assert torch.allclose(out[b], apply_rope(x[b], pos[b]), atol=1e-6)
    with pytest.raises(ValueError, match="positions"):
        apply_rope(x, torch.arange(4))


def test_attention_projection_names_and_padding_mask():
    attn = MultiHeadAttention(16, 4, kv_dim=12).eval()
    names = {n for n, _ in attn.named_modules()}
    assert {"q_proj", "k_proj", "v_proj", "out_proj"} <= names
    g = torch.Generator().manual_seed(3)
    x = torch.randn(2, 5, 16, generator=g)
    ctx = torch.randn(2, 6, 12, generator=g)
    pad = torch.zeros(2, 6, dtype=torch.bool)
    pad[:, 4:] = True
    out = attn(x, ctx, key_padding_mask=pad)
    # Padded tokens are ignored: changing them changes nothing; dropping them is identical.
    ctx2 = ctx.clone()
    ctx2[:, 4:] = 100.0
    assert torch.allclose(out, attn(x, ctx2, key_padding_mask=pad), atol=1e-6)
    assert torch.allclose(out, attn(x, ctx[:, :4]), atol=1e-6)
    with pytest.raises(ValueError, match="every key"):
        attn(x, ctx, key_padding_mask=torch.ones(2, 6, dtype=torch.bool))


def test_attention_matches_manual_softmax():
    attn = MultiHeadAttention(8, 2).eval()
    x = torch.randn(1, 3, 8, generator=torch.Generator().manual_seed(4))
    q = attn.q_proj(x).view(1, 3, 2, 4).transpose(1, 2)
    k = attn.k_proj(x).view(1, 3, 2, 4).transpose(1, 2)
    v = attn.v_proj(x).view(1, 3, 2, 4).transpose(1, 2)
    w = torch.softmax(q @ k.transpose(-1, -2) / 2.0, dim=-1)
    manual = attn.out_proj((w @ v).transpose(1, 2).reshape(1, 3, 8))
    assert torch.allclose(attn(x), manual, atol=1e-6)


@pytest.mark.parametrize("with_padding", [False, True])
def test_causal_block_ignores_future_positions(with_padding):
    torch.manual_seed(0)
    block = TransformerBlock(16, 4, context_dim=16, use_rope=True, causal=True).eval()
    g = torch.Generator().manual_seed(5)
    x = torch.randn(2, 6, 16, generator=g)
    ctx = torch.randn(2, 3, 16, generator=g)
    pad = torch.tensor([[False, False, True]] * 2) if with_padding else None
    out = block(x, ctx, pad)
    x2 = x.clone()
    x2[:, 3:] += 5.0 * torch.randn(2, 3, 16, generator=g)
    out2 = block(x2, ctx, pad)
    assert torch.allclose(out[:, :3], out2[:, :3], atol=1e-6)
    assert not torch.allclose(out[:, 3:], out2[:, 3:], atol=1e-3)
    # Without the causal mask, earlier outputs do see the future.
    nc, nc2 = block(x, ctx, pad, causal=False), block(x2, ctx, pad, causal=False)
    assert not torch.allclose(nc[:, :3], nc2[:, :3], atol=1e-3)


def test_build_attention_mask_combines_causal_and_padding():
    pad = torch.tensor([[False, False, True]])
    m = build_attention_mask(3, 3, pad, causal=True)
    expect = torch.tensor([[1, 0, 0], [1, 1, 0], [1, 1, 0]], dtype=torch.bool)
    assert torch.equal(m[0, 0], expect)
    assert build_attention_mask(3, 3) is None
    with pytest.raises(ValueError, match="T == S"):
        build_attention_mask(2, 3, causal=True)


@pytest.mark.parametrize("use_rope", [True, False])
def test_trajectory_encoder_shapes_seed_call(use_rope):
    enc = TrajectoryEncoder(7, 32, 2, 10, use_rope)  # the seed's positional call
    vec = torch.randn(3, 32)
    tokens = torch.randn(3, 5, 32)
    assert enc(context=vec, num_actions=4).shape == (3, 4, 7)
    assert enc(context=tokens, num_actions=10).shape == (3, 10, 7)
    assert enc(context=tokens).shape == (3, 10, 7)
    with pytest.raises(ValueError, match="num_actions"):
        enc(context=vec, num_actions=11)
    with pytest.raises(ValueError, match="context"):
        enc(context=torch.randn(3, 5, 31))


def test_trajectory_encoder_causal_prefix_consistency():
    torch.manual_seed(0)
    enc = TrajectoryEncoder(3, 32, 2, 8, use_rope=True, num_heads=4, causal=True).eval()
    ctx = torch.randn(2, 4, 32)
    full = enc(context=ctx, num_actions=8)
    # Autoregressive rollout: a shorter chunk equals the prefix of the longer one.
    assert torch.allclose(enc(context=ctx, num_actions=5), full[:, :5], atol=1e-5)
    # Perturbing later queries leaves earlier actions unchanged.
    with torch.no_grad():
        enc.queries[6:] += torch.randn(2, 32)
    after = enc(context=ctx, num_actions=8)
    assert torch.allclose(after[:, :6], full[:, :6], atol=1e-6)
    assert not torch.allclose(after[:, 6:], full[:, 6:], atol=1e-3)
    bidir = enc(context=ctx, num_actions=8, causal=False)
    assert not torch.allclose(enc(context=ctx, num_actions=5, causal=False), bidir[:, :5])


def test_trajectory_encoder_gradient_checkpointing_same_grads():
    torch.manual_seed(0)
    enc = TrajectoryEncoder(4, 32, 2, 6, context_dim=12)
    ctx = torch.randn(2, 3, 12)
    enc(context=ctx).square().sum().backward()
    ref = [p.grad.clone() for p in enc.parameters()]
    enc.zero_grad()
    enc.gradient_checkpointing = True
    enc(context=ctx).square().sum().backward()
    for r, p in zip(ref, enc.parameters()):
        assert torch.allclose(r, p.grad, atol=1e-6)


def test_trajectory_encoder_bad_arguments():
    with pytest.raises(ValueError, match="hidden_dim"):
        TrajectoryEncoder(7, 0, 2, 4)
    with pytest.raises(ValueError, match="num_heads"):
        TrajectoryEncoder(7, 30, 2, 4, num_heads=4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cached_rope_path_equals_explicit_positions(dtype):
    torch.manual_seed(0)
    attn = MultiHeadAttention(16, 2, use_rope=True).to(dtype).eval()
    x = torch.randn(2, 6, 16, dtype=dtype)
    cached = attn(x)  # float32: complex multiply; float64: cos/sin tables
    explicit = attn(x, positions=torch.arange(6))  # reference apply_rope
    assert torch.allclose(cached, explicit, atol=1e-5)
    shifted = attn(x, positions=torch.arange(6) + 40)  # relative positions unchanged
    assert torch.allclose(cached, shifted, atol=1e-4)
    assert not torch.allclose(cached, MultiHeadAttention(16, 2).to(dtype).eval()(x))


def test_precomputed_cross_kv_equals_context_path():
    torch.manual_seed(0)
    block = TransformerBlock(16, 4, context_dim=8).eval()
    x, ctx = torch.randn(2, 5, 16), torch.randn(2, 3, 8)
    pad = torch.tensor([[False, False, True], [False, False, False]])
    kv = block.cross_attn.project_kv(ctx)
    assert kv[0].shape == (2, 4, 3, 4)
    assert torch.allclose(block(x, ctx, pad), block(x, None, pad, context_kv=kv), atol=1e-6)
    with pytest.raises(ValueError, match="context"):
        block(x)
