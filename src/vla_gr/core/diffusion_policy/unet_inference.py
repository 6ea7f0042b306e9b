"""Small-input convolutions and the batch-1 fast sampling step of the 1-D conv U-Net.

At batch 1 the U-Net's tensors are tiny (``(1, C, L)`` with ``L <= 32``), so a sampling
step costs per-op overhead, not arithmetic: PyTorch's CPU ``conv1d`` takes a slow path
for such inputs, and every module call, GroupNorm wrapper and layout shuffle adds
microseconds. Two tools here remove most of that without changing the maths:

- :class:`FastConv1d` / :class:`FastConvTranspose1d`: drop-in ``nn.Conv1d`` /
  ``nn.ConvTranspose1d`` that compute small inputs as an im2col matmul (used in training
  and in the reference path).
- :class:`UnetStepPlan`: a flat list of the U-Net's per-step operations for one batch-1
  chunk. Every convolution is two matmuls: ``im2col = x @ S`` with a constant 0/1
  selection matrix ``S`` (zero padding and stride included) and ``cols @ W^T`` in the
  orientation BLAS is fast at (few rows, many columns); GroupNorm, Mish and FiLM are
  plain functional calls, with no module calls or per-op layout copies in between.

How the plan stays in sync with the weights: a plan holds only *views* of the
parameters (``weight.view(...).t()``), never copies, and is built afresh for every
sampled chunk (``ConditionalUnet1D.sampling_step``, ~0.2 ms), so in-place updates
(optimizer steps, ``load_state_dict``), replaced parameters (``.to()``, merging LoRA)
and structural changes are all seen by the next chunk. The only cached tensors are the
selection matrices, which depend on shapes alone. Modules it does not know exactly
(e.g. a conv wrapped by an unmerged LoRA adapter) make :meth:`UnetStepPlan.build`
return ``None`` and the caller falls back to the reference step.

Next in the data flow: the sampling loop of :mod:`vla_gr.core.diffusion_policy.head` calls it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

__all__ = [
    "FastConv1d",
    "FastConvTranspose1d",
    "conv_selection",
    "conv_transpose_selection",
    "UnetStepPlan",
]

# Below this many output rows (batch * length), a conv is one im2col matmul: PyTorch's
# CPU conv1d falls back to a slow path for tiny batch-1 inputs (measured 400 us vs 80 us
# for 256 channels at length 4), which dominates batch-1 sampling latency.
# Small kernels (fewer weights than this) are faster in PyTorch's own conv.
_MATMUL_MAX_ROWS = 64
_MATMUL_MIN_WEIGHTS = 10_000


class FastConv1d(nn.Conv1d):
    """``nn.Conv1d`` (groups=1, dilation=1) computed as an im2col matmul for small inputs."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, C_in, L) -> (B, C_out, L_out)``."""
        B, C, L = x.shape
        k, s, p = self.kernel_size[0], self.stride[0], self.padding[0]
        L_out = (L + 2 * p - k) // s + 1
        if (
            B * L_out > _MATMUL_MAX_ROWS
            or self.in_channels * self.out_channels * k < _MATMUL_MIN_WEIGHTS
            or self.groups != 1
            or self.dilation[0] != 1
        ):
            return super().forward(x)
        xp = F.pad(x, (p, p)) if p else x  # (B, C, L + 2p)
        cols = xp.unfold(2, k, s).permute(0, 2, 1, 3).reshape(B * L_out, C * k)  # (B*Lo, C*k)
        y = F.linear(cols, self.weight.view(self.out_channels, C * k), self.bias)  # (B*Lo, Co)
        return y.view(B, L_out, self.out_channels).transpose(1, 2)  # (B, C_out, Lo)


class FastConvTranspose1d(nn.ConvTranspose1d):
    """``nn.ConvTranspose1d`` (groups=1) computed as matmul + col2im for small inputs."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, C_in, L) -> (B, C_out, (L - 1) * stride - 2 * padding + kernel)``."""
        B, C, L = x.shape
        k, s, p = self.kernel_size[0], self.stride[0], self.padding[0]
        if (
            B * L * s > _MATMUL_MAX_ROWS
            or self.groups != 1
            or self.dilation[0] != 1
            or self.output_padding[0] != 0
        ):
            return super().forward(x)
        w = self.weight.view(C, self.out_channels * k)  # (C_in, C_out*k)
        cols = (x.transpose(1, 2).reshape(B * L, C) @ w).view(B, L, -1)  # (B, L, C_out*k)
        full = (L - 1) * s + k
        y = F.fold(
            cols.transpose(1, 2), output_size=(1, full), kernel_size=(1, k), stride=(1, s)
        )  # (B, C_out, 1, full)
        y = y[:, :, 0, p : full - p]  # (B, C_out, L_out)
        return y if self.bias is None else y + self.bias[:, None]


# ---------------------------------------------------------------- selection matrices


@functools.lru_cache(maxsize=128)
def _selection(
    transpose: bool, length: int, kernel: int, stride: int, padding: int, dtype, device
) -> torch.Tensor:
    with torch.inference_mode(False), torch.no_grad():  # an ordinary constant tensor
        if transpose:
            out_len = (length - 1) * stride - 2 * padding + kernel
            m = torch.zeros(out_len, length, kernel, dtype=dtype)  # (Lo, L, k)
        else:
            out_len = (length + 2 * padding - kernel) // stride + 1
            m = torch.zeros(length, kernel, out_len, dtype=dtype)  # (L, k, Lo)
        for j in range(kernel):
            for i in range(out_len if not transpose else length):
                # conv: output i reads input i*s + j - p; transposed: input i writes there
                pos = i * stride + j - padding
                if transpose and 0 <= pos < out_len:
                    m[pos, i, j] = 1.0
                elif not transpose and 0 <= pos < length:
                    m[pos, j, i] = 1.0
        return m.flatten(1).to(device)


def conv_selection(
    length: int, kernel: int, stride: int, padding: int, like: torch.Tensor
) -> torch.Tensor:
    """0/1 im2col matrix of a zero-padded 1-D conv: ``(x @ S)[c, j * Lo + i] = x_pad[c, i*s + j]``.

    Args:
        length: input length ``L``.
        kernel, stride, padding: conv geometry.
        like: tensor whose dtype / device the result takes.

    Returns:
        ``(L, kernel * L_out)``, cached (do not modify).
    """
    return _selection(False, length, kernel, stride, padding, like.dtype, like.device)


def conv_transpose_selection(
    length: int, kernel: int, stride: int, padding: int, like: torch.Tensor
) -> torch.Tensor:
    """0/1 col2im matrix of a 1-D transposed conv: ``T[o, i * k + j] = 1`` iff ``o = i*s + j - p``.

    Args:
        length: input length ``L``.
        kernel, stride, padding: transposed-conv geometry (``output_padding = 0``).
        like: tensor whose dtype / device the result takes.

    Returns:
        ``(L_out, L * kernel)``, cached (do not modify).
    """
    return _selection(True, length, kernel, stride, padding, like.dtype, like.device)


# ---------------------------------------------------------------- the step plan


class _Conv(NamedTuple):
    sel: torch.Tensor | None  # (L, k * Lo) im2col selection; None for 1x1 stride-1 convs
    c_in: int
    l_in: int
    rows: int  # C_in * k
    l_out: int
    weight_t: torch.Tensor  # (C_in * k, C_out) view of the weight
    bias: torch.Tensor | None  # (C_out,)


class _ConvTranspose(NamedTuple):
    sel: torch.Tensor  # (Lo, L * k) col2im selection
    c_in: int
    l_in: int
    c_out: int
    kernel: int
    weight: torch.Tensor  # (C_in, C_out * k) view of the weight
    bias: torch.Tensor | None  # (C_out,)


class _ConvNormAct(NamedTuple):
    conv: _Conv
    groups: int
    weight: torch.Tensor | None
    bias: torch.Tensor | None
    eps: float


class _ResBlock(NamedTuple):
    block1: _ConvNormAct
    block2: _ConvNormAct
    residual: _Conv | None


class _UnsupportedError(Exception):
    """A module the plan does not know exactly (the caller uses the reference step)."""


def _plan_conv(m: nn.Module, like: torch.Tensor, length: int) -> _Conv:
    if type(m) not in (FastConv1d, nn.Conv1d) or (m.groups, m.dilation[0]) != (1, 1):
        raise _UnsupportedError(type(m).__name__)
    if m.padding_mode != "zeros" or isinstance(m.padding, str):
        raise _UnsupportedError("conv padding")
    k, s, p = m.kernel_size[0], m.stride[0], m.padding[0]
    c_in, c_out = m.in_channels, m.out_channels
    l_out = (length + 2 * p - k) // s + 1
    sel = None if (k, s, p) == (1, 1, 0) else conv_selection(length, k, s, p, like)
    w_t = m.weight.view(c_out, c_in * k).t()  # (C_in*k, C_out), a view
    return _Conv(sel, c_in, length, c_in * k, l_out, w_t, m.bias)


def _plan_conv_norm_act(block: nn.Module, like: torch.Tensor, length: int) -> _ConvNormAct:
    conv, norm, act = block  # iterating is cheaper than Sequential indexing
    if type(norm) is not nn.GroupNorm or type(act) is not nn.Mish:
        raise _UnsupportedError("conv block")
    return _ConvNormAct(
        _plan_conv(conv, like, length), norm.num_groups, norm.weight, norm.bias, norm.eps
    )


def _plan_res(blk: nn.Module, like: torch.Tensor, length: int) -> _ResBlock:
    res = None if type(blk.residual) is nn.Identity else _plan_conv(blk.residual, like, length)
    return _ResBlock(
        _plan_conv_norm_act(blk.block1, like, length),
        _plan_conv_norm_act(blk.block2, like, length),
        res,
    )


def _plan_up(m: nn.Module, like: torch.Tensor, length: int) -> _ConvTranspose:
    if type(m) not in (FastConvTranspose1d, nn.ConvTranspose1d):
        raise _UnsupportedError(type(m).__name__)
    if (m.groups, m.dilation[0], m.output_padding[0], m.padding_mode) != (1, 1, 0, "zeros"):
        raise _UnsupportedError("transposed conv geometry")
    k, s, p = m.kernel_size[0], m.stride[0], m.padding[0]
    sel = conv_transpose_selection(length, k, s, p, like)
    w = m.weight.view(m.in_channels, m.out_channels * k)  # (C_in, C_out*k), a view
    return _ConvTranspose(sel, m.in_channels, length, m.out_channels, k, w, m.bias)


def _cudnn() -> bool:
    return torch.backends.cudnn.enabled  # as F.group_norm passes it


def _conv(op: _Conv, x: torch.Tensor) -> torch.Tensor:
    """``x (1, C_in, L)`` (any strides) -> ``(L_out, C_out)`` (time-major)."""
    x2 = x.view(op.c_in, op.l_in)  # (C, L)
    # 1x1: (L, C); else im2col (Lo, C*k)
    cols = x2.t() if op.sel is None else torch.mm(x2, op.sel).view(op.rows, op.l_out).t()
    if op.bias is None:
        return torch.mm(cols, op.weight_t)  # (Lo, Co)
    return torch.addmm(op.bias, cols, op.weight_t)  # (Lo, Co)


def _conv_norm_act(op: _ConvNormAct, x: torch.Tensor) -> torch.Tensor:
    """``Mish(GroupNorm(conv(x)))``: ``(1, C_in, L) -> (1, C_out, L_out)``."""
    y = _conv(op.conv, x).t().unsqueeze(0)  # (1, Co, Lo)
    # torch.group_norm: F.group_norm without its Python-side checks (~5 us per call)
    y = torch.group_norm(y, op.groups, op.weight, op.bias, op.eps, _cudnn())  # (1, Co, Lo)
    return F.mish(y, inplace=True)


def _res_block(
    op: _ResBlock, x: torch.Tensor, scale: torch.Tensor, bias: torch.Tensor
) -> torch.Tensor:
    """Residual block with FiLM ``(1, Co, 1)``: ``(1, C_in, L) -> (1, Co, L)``."""
    h = torch.addcmul(bias, _conv_norm_act(op.block1, x), scale)  # (1, Co, L)
    out = _conv_norm_act(op.block2, h)  # (1, Co, L), fresh
    if op.residual is None:
        return out.add_(x)
    return out.add_(_conv(op.residual, x).t())  # (1, Co, L)


def _conv_transpose(op: _ConvTranspose, x: torch.Tensor) -> torch.Tensor:
    """``(1, C_in, L) -> (1, C_out, L_out)``: matmul, then col2im as a selection matmul."""
    z = torch.mm(x.view(op.c_in, op.l_in).t(), op.weight)  # (L, Co*k), (i, o, j) order
    z = z.view(op.l_in, op.c_out, op.kernel).transpose(1, 2)  # (L, k, Co)
    z = z.reshape(op.l_in * op.kernel, op.c_out)  # (L*k, Co)
    if op.bias is None:
        return torch.mm(op.sel, z).t().unsqueeze(0)
    return torch.addmm(op.bias, op.sel, z).t().unsqueeze(0)  # (1, Co, Lo)


class UnetStepPlan:
    """The batch-1 sampling step of the 1-D conv U-Net (``ConditionalUnet1D``).

    Build it with :meth:`build` once per chunk (it holds views of the current
    parameters; see the module docstring) and call it once per integration step. It
    computes the same function as ``ConditionalUnet1D.denoise_step`` (equal within
    float rounding).
    """

    def __init__(self, net: nn.Module, x: torch.Tensor) -> None:
        H = x.shape[1]
        length = H + (-H) % net._multiple
        self.horizon, self.pad = H, length - H
        self.downs = []
        for res1, res2, down in net.downs:
            pair = (_plan_res(res1, x, length), _plan_res(res2, x, length))
            dn = None if type(down) is nn.Identity else _plan_conv(down, x, length)
            self.downs.append((*pair, dn))
            length = length if dn is None else dn.l_out
        self.mids = [_plan_res(res, x, length) for res in net.mids]
        self.ups = []
        for res1, res2, up in net.ups:
            up_op = _plan_up(up, x, length)
            self.ups.append((_plan_res(res1, x, length), _plan_res(res2, x, length), up_op))
            length = up_op.sel.shape[0]
        final_block, final_conv = net.final
        self.final = (
            _plan_conv_norm_act(final_block, x, length),
            _plan_conv(final_conv, x, length),
        )

    @classmethod
    def build(cls, net: nn.Module, x: torch.Tensor) -> UnetStepPlan | None:
        """Plan for ``net`` and noisy actions like ``x (1, H, A)``; ``None`` if unsupported."""
        if x.dim() != 3 or x.shape[0] != 1:
            return None
        try:
            return cls(net, x)
        except _UnsupportedError:
            return None

    def __call__(
        self, x: torch.Tensor, films: list[tuple[torch.Tensor, torch.Tensor]]
    ) -> torch.Tensor:
        """One denoiser evaluation.

        Args:
            x: ``(1, H, A)`` noisy actions.
            films: per-block FiLM ``(scale, bias)``, each ``(1, out_ch, 1)`` (from
                ``ConditionalUnet1D.step_conditions``).

        Returns:
            ``(1, H, A)``.
        """
        h = x.transpose(1, 2)  # (1, A, H)
        if self.pad:
            h = F.pad(h, (0, self.pad))  # (1, A, L)
        it = iter(films)
        skips = []
        for res1, res2, down in self.downs:
            h = _res_block(res2, _res_block(res1, h, *next(it)), *next(it))  # (1, d, L)
            skips.append(h)
            if down is not None:
                h = _conv(down, h).t().unsqueeze(0)  # (1, d, L/2)
        for res in self.mids:
            h = _res_block(res, h, *next(it))  # (1, d_mid, L)
        for res1, res2, up in self.ups:
            h = torch.cat((h, skips.pop()), dim=1)  # (1, 2d, L)
            h = _res_block(res2, _res_block(res1, h, *next(it)), *next(it))  # (1, d', L)
            h = _conv_transpose(up, h)  # (1, d', 2L)
        block, conv = self.final
        out = _conv(conv, _conv_norm_act(block, h))  # (L, A)
        return out[: self.horizon].unsqueeze(0)  # (1, H, A)
