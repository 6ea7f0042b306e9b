"""Attention blocks: SDPA multi-head attention with RoPE, the pre-norm ``TransformerBlock``.

The building blocks of the trajectory transformer (Actra / X-VLA style) and of the
transformer denoiser of the action heads:

- :func:`apply_rope` (from :mod:`vla_gr.core.trajectory_attention.rope`) -- rotary
  position embeddings (RoFormer): dimension pairs ``(2i, 2i+1)`` are rotated by
  ``position * theta_i`` with ``theta_i = base ** (-2i / D)``, so ``q_m . k_n``
  depends only on ``m - n``.
- :class:`MultiHeadAttention` -- self or cross attention on
  :func:`torch.nn.functional.scaled_dot_product_attention` (fused / flash kernels on
  GPU) with projections named ``q_proj``, ``k_proj``, ``v_proj``, ``out_proj`` so that
  PEFT (LoRA / OFT) can target them; key padding masks, causal masks, optional RoPE.
- :class:`TransformerBlock` -- pre-norm self-attention, optional cross-attention, MLP.

Masks follow PyTorch's ``nn.MultiheadAttention``: ``key_padding_mask`` is bool
``(B, S)`` with ``True`` marking padded (ignored) tokens. Next in the data flow:
:mod:`vla_gr.core.trajectory_attention.encoder` (action queries built from these blocks).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.core.trajectory_attention.rope import (
    apply_rope,
    apply_rope_complex,
    apply_rope_tables,
    rope_angles,
    rope_tables,
)

__all__ = [
    "build_attention_mask",
    "MultiHeadAttention",
    "TransformerBlock",
    "as_context_tokens",
]


# --------------------------------------------------------------------------- masks


def build_attention_mask(
    num_queries: int,
    num_keys: int,
    key_padding_mask: torch.Tensor | None = None,
    causal: bool = False,
    device: torch.device | None = None,
) -> torch.Tensor | None:
    """Boolean SDPA mask (``True`` = may attend) combining padding and causality.

    Args:
        num_queries: ``T`` query tokens.
        num_keys: ``S`` key tokens.
        key_padding_mask: optional bool ``(B, S)``, ``True`` = padded (ignored).
        causal: query ``i`` sees keys ``j <= i`` only (requires ``T == S``).
        device: device of the mask when no padding mask is given.

    Returns:
        ``None`` when nothing is masked, else bool ``(T, S)`` or ``(B, 1, T, S)``.
    """
    mask = None
    if causal:
        if num_queries != num_keys:
            raise ValueError(f"causal attention needs T == S; got T={num_queries}, S={num_keys}")
        dev = key_padding_mask.device if key_padding_mask is not None else device
        mask = torch.ones(num_queries, num_keys, dtype=torch.bool, device=dev).tril()  # (T, S)
    if key_padding_mask is not None:
        if key_padding_mask.dim() != 2 or key_padding_mask.shape[1] != num_keys:
            raise ValueError(
                f"key_padding_mask must be (B, {num_keys}); got {tuple(key_padding_mask.shape)}"
            )
        keep = ~key_padding_mask.bool()[:, None, None, :]  # (B, 1, 1, S)
        mask = keep if mask is None else keep & mask  # (B, 1, T, S)
        if not bool(mask.any(-1).all()):
            raise ValueError("key_padding_mask masks every key of some query (NaN attention)")
    return mask


# --------------------------------------------------------------------------- attention


class MultiHeadAttention(nn.Module):
    """Multi-head self/cross attention on ``scaled_dot_product_attention``.

    Args:
        dim: query/model width ``D`` (divisible by ``num_heads``).
        num_heads: attention heads.
        kv_dim: width of key/value inputs for cross attention (default ``dim``).
        dropout: attention dropout probability (training only).
        bias: bias in the projections.
        use_rope: rotate queries and keys by their positions (self attention).
        rope_base: RoPE frequency base.
    """

    def __init__(
        self,
        dim: int,
        num_heads: int = 4,
        kv_dim: int | None = None,
        dropout: float = 0.0,
        bias: bool = True,
        use_rope: bool = False,
        rope_base: float = 10000.0,
    ) -> None:
        super().__init__()
        if dim <= 0 or num_heads <= 0 or dim % num_heads != 0:
            raise ValueError(f"dim={dim} must be a positive multiple of num_heads={num_heads}")
        head_dim = dim // num_heads
        if use_rope and head_dim % 2 != 0:
            raise ValueError(f"use_rope needs an even head_dim; got dim/num_heads={head_dim}")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout={dropout} must be in [0, 1)")
        kv_dim = dim if kv_dim is None else kv_dim
        self.num_heads, self.head_dim, self.dropout = num_heads, head_dim, dropout
        self.use_rope, self.rope_base = use_rope, rope_base
        self.q_proj = nn.Linear(dim, dim, bias=bias)
        self.k_proj = nn.Linear(kv_dim, dim, bias=bias)
        self.v_proj = nn.Linear(kv_dim, dim, bias=bias)
        self.out_proj = nn.Linear(dim, dim, bias=bias)
        self._rope_cache: dict[tuple, tuple[torch.Tensor, ...]] = {}

    def _rope(self, n: int, like: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Cached RoPE tables for positions ``0..n-1`` in the dtype of ``like``.

        Returns ``(cis,)`` ``(n, head_dim/2)`` complex64 for float32 (one complex multiply
        per tensor, the fastest form on CPU), else ``(cos2, sin2)`` ``(n, head_dim)``.
        """
        key = (n, like.device, like.dtype)
        if key not in self._rope_cache:
            with torch.inference_mode(False), torch.no_grad():
                pos = torch.arange(n, device=like.device)  # (n,)
                cos, sin = rope_angles(pos, self.head_dim, self.rope_base)  # (n, d/2)
                if like.dtype == torch.float32:
                    self._rope_cache[key] = (torch.complex(cos, sin),)  # (n, d/2)
                else:
                    self._rope_cache[key] = tuple(t.to(like.dtype) for t in rope_tables(cos, sin))
        return self._rope_cache[key]

    def project_kv(self, context: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Keys and values of a memory, to reuse across calls (cross attention).

        Args:
            context: ``(B, S, kv_dim)``.

        Returns:
            ``(k, v)``, each ``(B, heads, S, head_dim)``.
        """
        B, S, _ = context.shape
        k = self.k_proj(context).view(B, S, self.num_heads, self.head_dim).transpose(1, 2)
        v = self.v_proj(context).view(B, S, self.num_heads, self.head_dim).transpose(1, 2)
        return k, v  # (B, h, S, d) each

    def forward(
        self,
        x: torch.Tensor,
        context: torch.Tensor | None = None,
        key_padding_mask: torch.Tensor | None = None,
        causal: bool = False,
        positions: torch.Tensor | None = None,
        context_positions: torch.Tensor | None = None,
        kv: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Attend from ``x`` to itself (``context=None``) or to ``context``.

        Args:
            x: ``(B, T, D)`` queries.
            context: optional ``(B, S, kv_dim)`` keys/values (cross attention).
            key_padding_mask: optional bool ``(B, S)`` (``S = T`` for self attention),
                ``True`` = padded key.
            causal: causal mask (self attention).
            positions: optional ``(T,)`` or ``(B, T)`` query positions for RoPE
                (default ``0..T-1``).
            context_positions: ``(S,)`` or ``(B, S)`` key positions for RoPE in cross
                attention; RoPE is applied to cross attention only when given.
            kv: precomputed ``(k, v)`` ``(B, heads, S, head_dim)`` from :meth:`project_kv`
                (cross attention without recomputing the memory's projections).

        Returns:
            ``(B, T, D)``.
        """
        B, T, _ = x.shape
        q = self.q_proj(x).view(B, T, self.num_heads, self.head_dim).transpose(1, 2)  # (B,h,T,d)
        if kv is None:
            k, v = self.project_kv(x if context is None else context)  # (B, h, S, d) each
        else:
            k, v = kv  # (B, h, S, d) each
            context = k  # marks cross attention below
        S = k.shape[2]
        if self.use_rope:
            if context is None:
                if positions is None:
                    tables = self._rope(T, q)
                    if len(tables) == 1:  # float32: complex form, (T, d/2)
                        q, k = apply_rope_complex(q, tables[0]), apply_rope_complex(k, tables[0])
                    else:  # (T, d) each
                        q, k = apply_rope_tables(q, *tables), apply_rope_tables(k, *tables)
                else:
                    q = apply_rope(q, positions, self.rope_base)
                    k = apply_rope(k, positions, self.rope_base)
            elif context_positions is not None:
                q_pos = positions if positions is not None else torch.arange(T, device=x.device)
                q = apply_rope(q, q_pos, self.rope_base)
                k = apply_rope(k, context_positions, self.rope_base)
        if key_padding_mask is None:
            attn_mask, is_causal = None, causal
        else:
            attn_mask, is_causal = build_attention_mask(T, S, key_padding_mask, causal), False
        p = self.dropout if self.training else 0.0
        out = F.scaled_dot_product_attention(
            q, k, v, attn_mask=attn_mask, dropout_p=p, is_causal=is_causal
        )  # (B, h, T, d)
        out = out.transpose(1, 2).reshape(B, T, self.num_heads * self.head_dim)  # (B, T, D)
        return self.out_proj(out)  # (B, T, D)


class TransformerBlock(nn.Module):
    """Pre-norm block: ``x + SelfAttn(LN x)``, ``x + CrossAttn(LN x, ctx)``, ``x + MLP(LN x)``.

    Args:
        dim: model width ``D``.
        num_heads: attention heads.
        context_dim: width of the cross-attention memory; ``None`` = no cross attention.
        mlp_ratio: hidden width of the MLP as a multiple of ``dim``.
        dropout: dropout on attention weights and residual branches.
        use_rope: RoPE in the self-attention.
        causal: causal self-attention by default (overridable per call).
    """

    def __init__(
        self,
        dim: int,
        num_heads: int = 4,
        context_dim: int | None = None,
        mlp_ratio: float = 4.0,
        dropout: float = 0.0,
        use_rope: bool = True,
        causal: bool = False,
    ) -> None:
        super().__init__()
        self.causal = causal
        self.norm1 = nn.LayerNorm(dim)
        self.self_attn = MultiHeadAttention(dim, num_heads, dropout=dropout, use_rope=use_rope)
        self.has_cross = context_dim is not None
        if self.has_cross:
            self.norm2 = nn.LayerNorm(dim)
            self.cross_attn = MultiHeadAttention(
                dim, num_heads, kv_dim=context_dim, dropout=dropout
            )
        hidden = int(dim * mlp_ratio)
        self.norm3 = nn.LayerNorm(dim)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))
        self.drop = nn.Dropout(dropout) if dropout > 0 else nn.Identity()

    def forward(
        self,
        x: torch.Tensor,
        context: torch.Tensor | None = None,
        context_padding_mask: torch.Tensor | None = None,
        causal: bool | None = None,
        positions: torch.Tensor | None = None,
        context_kv: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Apply the block.

        Args:
            x: ``(B, T, D)`` tokens.
            context: ``(B, S, context_dim)`` memory (required when built with cross attention).
            context_padding_mask: optional bool ``(B, S)``, ``True`` = padded.
            causal: override the block's default causality.
            positions: optional ``(T,)`` or ``(B, T)`` RoPE positions.
            context_kv: optional precomputed cross-attention ``(k, v)`` of the context
                (``self.cross_attn.project_kv(context)``), used instead of ``context``.

        Returns:
            ``(B, T, D)``.
        """
        causal = self.causal if causal is None else causal
        x = x + self.drop(self.self_attn(self.norm1(x), causal=causal, positions=positions))
        if self.has_cross:
            if context is None and context_kv is None:
                raise ValueError("this block cross-attends: context (B, S, C) is required")
            h = self.cross_attn(
                self.norm2(x), context, key_padding_mask=context_padding_mask, kv=context_kv
            )
            x = x + self.drop(h)  # (B, T, D)
        return x + self.drop(self.mlp(self.norm3(x)))  # (B, T, D)


def as_context_tokens(context: torch.Tensor, context_dim: int | None = None) -> torch.Tensor:
    """Turn a ``(B, C)`` vector or ``(B, T, C)`` tokens into ``(B, T, C)`` tokens.

    Args:
        context: ``(B, C)`` or ``(B, T, C)``.
        context_dim: expected ``C`` (checked when given).

    Returns:
        ``(B, T, C)`` (``T = 1`` for a vector).
    """
    if context.dim() == 2:
        context = context.unsqueeze(1)  # (B, 1, C)
    if context.dim() != 3:
        raise ValueError(f"context must be (B, C) or (B, T, C); got {tuple(context.shape)}")
    if context_dim is not None and context.shape[-1] != context_dim:
        raise ValueError(f"context has C={context.shape[-1]} but context_dim={context_dim}")
    return context
