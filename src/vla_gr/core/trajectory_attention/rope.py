"""Rotary position embeddings (RoFormer), as pure functions.

Dimension pairs ``(2i, 2i+1)`` of a ``D``-wide feature at position ``p`` are rotated
by the angle ``p * theta_i`` with ``theta_i = base ** (-2i / D)``. Rotations preserve
norms, and ``<R(m) q, R(n) k>`` depends only on ``m - n``, so attention scores see
relative positions. Three equivalent forms: :func:`apply_rope` (reference),
:func:`apply_rope_complex` (one complex multiply, fastest on CPU for float32) and
:func:`apply_rope_tables` (real arithmetic for any dtype).

Next in the data flow: :mod:`vla_gr.core.trajectory_attention.attention`.
"""

from __future__ import annotations

import torch

__all__ = [
    "rope_angles",
    "apply_rope",
    "apply_rope_cos_sin",
    "rope_tables",
    "apply_rope_tables",
    "apply_rope_complex",
]


def rope_angles(
    positions: torch.Tensor, dim: int, base: float = 10000.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cosines and sines of the rotary angles ``position * theta_i``.

    Args:
        positions: ``(T,)`` or ``(B, T)`` positions (integer or float).
        dim: even feature size ``D`` that will be rotated.
        base: frequency base; ``theta_i = base ** (-2i / D)``.

    Returns:
        ``(cos, sin)``, each ``(T, D/2)`` or ``(B, T, D/2)`` in float32.
    """
    if dim % 2 != 0 or dim <= 0:
        raise ValueError(f"dim={dim} must be a positive even number for RoPE")
    if positions.dim() not in (1, 2):
        raise ValueError(f"positions must be (T,) or (B, T); got shape {tuple(positions.shape)}")
    idx = torch.arange(0, dim, 2, device=positions.device, dtype=torch.float32)  # (D/2,)
    inv_freq = base ** (-idx / dim)  # (D/2,)
    angles = positions.to(torch.float32).unsqueeze(-1) * inv_freq  # (..., T, D/2)
    return angles.cos(), angles.sin()


def apply_rope_cos_sin(x: torch.Tensor, cos: torch.Tensor, sin: torch.Tensor) -> torch.Tensor:
    """Rotate pairs ``(x[..., 2i], x[..., 2i+1])`` by precomputed angles.

    Args:
        x: ``(..., T, D)`` features; ``(B, ..., T, D)`` when ``cos`` is batched.
        cos: ``(T, D/2)`` or ``(B, T, D/2)`` from :func:`rope_angles`.
        sin: same shape as ``cos``.

    Returns:
        Tensor of the shape and dtype of ``x``.
    """
    if cos.dim() == 3 and x.dim() > 3:
        # (B, T, D/2) -> (B, 1, ..., 1, T, D/2) to broadcast over head dims.
        shape = (cos.shape[0],) + (1,) * (x.dim() - 3) + cos.shape[1:]
        cos, sin = cos.view(shape), sin.view(shape)
    xf = x.float().unflatten(-1, (-1, 2))  # (..., T, D/2, 2)
    x1, x2 = xf[..., 0], xf[..., 1]  # (..., T, D/2)
    out = torch.stack((x1 * cos - x2 * sin, x1 * sin + x2 * cos), dim=-1)  # (..., T, D/2, 2)
    return out.flatten(-2).to(x.dtype)  # (..., T, D)


def rope_tables(cos: torch.Tensor, sin: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Interleaved full-width tables for :func:`apply_rope_tables`.

    Args:
        cos: ``(..., T, D/2)`` from :func:`rope_angles`.
        sin: same shape.

    Returns:
        ``(cos2, sin2)``, each ``(..., T, D)``: ``[c0, c0, c1, c1, ...]`` and
        ``[-s0, s0, -s1, s1, ...]``.
    """
    cos2 = cos.repeat_interleave(2, dim=-1)  # (..., T, D)
    sin2 = torch.stack((-sin, sin), dim=-1).flatten(-2)  # (..., T, D)
    return cos2, sin2


def apply_rope_tables(x: torch.Tensor, cos2: torch.Tensor, sin2: torch.Tensor) -> torch.Tensor:
    """RoPE as ``x * cos2 + swap_pairs(x) * sin2`` (4 ops; same result as :func:`apply_rope`).

    Args:
        x: ``(..., T, D)``.
        cos2: ``(T, D)`` from :func:`rope_tables` (in the dtype of ``x``).
        sin2: ``(T, D)``.

    Returns:
        ``(..., T, D)``.
    """
    swapped = x.unflatten(-1, (-1, 2)).flip(-1).flatten(-2)  # (..., T, D): (x1, x0, x3, x2..)
    return x * cos2 + swapped * sin2


def apply_rope_complex(x: torch.Tensor, cis: torch.Tensor) -> torch.Tensor:
    """RoPE as one complex multiply (LLaMA style); float32 ``x`` only.

    Args:
        x: ``(..., T, D)`` float32 with unit stride in the last dim.
        cis: ``(T, D/2)`` complex64 ``cos + i sin`` (``torch.polar(1, angle)``).

    Returns:
        ``(..., T, D)`` float32.
    """
    xc = torch.view_as_complex(x.unflatten(-1, (-1, 2)))  # (..., T, D/2) complex
    return torch.view_as_real(xc * cis).flatten(-2)  # (..., T, D)


def apply_rope(x: torch.Tensor, positions: torch.Tensor, base: float = 10000.0) -> torch.Tensor:
    """Rotary position embedding of ``x`` at ``positions`` (norm preserving).

    Args:
        x: ``(..., T, D)`` with ``D`` even (e.g. ``(B, heads, T, head_dim)``).
        positions: ``(T,)`` shared positions or ``(B, T)`` per-sample positions
            (then ``x`` must have the batch as its first dimension).
        base: frequency base of ``theta_i = base ** (-2i / D)``.

    Returns:
        Tensor with the shape of ``x``.
    """
    if x.shape[-2] != positions.shape[-1]:
        raise ValueError(
            f"positions has {positions.shape[-1]} entries but x has T={x.shape[-2]} tokens"
        )
    cos, sin = rope_angles(positions.to(x.device), x.shape[-1], base)  # (..., T, D/2)
    return apply_rope_cos_sin(x, cos, sin)
