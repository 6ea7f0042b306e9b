"""Denoisers: fast conv paths equal PyTorch's, precomputed step conditions equal forward."""

import pytest
import torch
from torch import nn

from vla_gr.core.denoisers import (
    ConditionalUnet1D,
    FastConv1d,
    FastConvTranspose1d,
    TransformerDenoiser,
    masked_mean,
    sinusoidal_embedding,
)


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
