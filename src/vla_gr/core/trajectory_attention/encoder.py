"""``TrajectoryEncoder``: learnable action queries (DETR-style) over context tokens.

The queries self-attend (with RoPE positions, optionally causally for autoregressive
rollout) and cross-attend to the context, built from the blocks of
:mod:`vla_gr.core.trajectory_attention.attention`. Next in the data flow: the L1 head
(:mod:`vla_gr.core.diffusion_policy.regression_head`) decodes action chunks with it.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.utils.checkpoint import checkpoint

from vla_gr.core.trajectory_attention.attention import TransformerBlock, as_context_tokens
from vla_gr.validation import check_positive_int

__all__ = ["TrajectoryEncoder"]


class TrajectoryEncoder(nn.Module):
    """Learnable action queries that self-attend and cross-attend to context tokens.

    DETR-style decoding of an action chunk in one pass: ``num_action_queries``
    learned query embeddings go through pre-norm blocks (self attention with RoPE
    positions, optionally causal for autoregressive rollout; cross attention to the
    context), then a linear head maps each query to an action.

    Args:
        action_dim: output action size ``A``.
        hidden_dim: model width ``D``.
        num_layers: number of blocks.
        num_action_queries: maximum chunk length ``K_max``.
        use_rope: rotary positions in the self-attention (else learned absolute
            positions are added to the queries).
        num_heads: attention heads.
        causal: causal self-attention (query ``k`` only sees queries ``<= k``).
        context_dim: width ``C`` of the context (default ``hidden_dim``).
        mlp_ratio: MLP width multiple.
        dropout: dropout probability.
        gradient_checkpointing: recompute block activations in backward (saves memory).
    """

    def __init__(
        self,
        action_dim: int = 7,
        hidden_dim: int = 256,
        num_layers: int = 4,
        num_action_queries: int = 16,
        use_rope: bool = True,
        num_heads: int = 4,
        causal: bool = False,
        context_dim: int | None = None,
        mlp_ratio: float = 4.0,
        dropout: float = 0.0,
        gradient_checkpointing: bool = False,
    ) -> None:
        super().__init__()
        for name, val in (
            ("action_dim", action_dim),
            ("hidden_dim", hidden_dim),
            ("num_layers", num_layers),
            ("num_action_queries", num_action_queries),
        ):
            check_positive_int(name, val)
        context_dim = hidden_dim if context_dim is None else context_dim
        self.action_dim, self.hidden_dim, self.context_dim = action_dim, hidden_dim, context_dim
        self.num_action_queries, self.use_rope, self.causal = num_action_queries, use_rope, causal
        self.gradient_checkpointing = gradient_checkpointing
        self.queries = nn.Parameter(torch.randn(num_action_queries, hidden_dim) * 0.02)  # (K, D)
        self.pos_embed = (
            None
            if use_rope
            else nn.Parameter(torch.randn(num_action_queries, hidden_dim) * 0.02)  # (K, D)
        )
        self.context_proj = nn.Linear(context_dim, hidden_dim)
        self.blocks = nn.ModuleList(
            TransformerBlock(
                hidden_dim, num_heads, hidden_dim, mlp_ratio, dropout, use_rope, causal
            )
            for _ in range(num_layers)
        )
        self.norm = nn.LayerNorm(hidden_dim)
        self.action_head = nn.Linear(hidden_dim, action_dim)

    def forward(
        self,
        context: torch.Tensor,
        num_actions: int | None = None,
        context_padding_mask: torch.Tensor | None = None,
        causal: bool | None = None,
    ) -> torch.Tensor:
        """Decode ``num_actions`` actions from the context.

        Args:
            context: ``(B, C)`` vector or ``(B, T, C)`` tokens.
            num_actions: chunk length ``K <= num_action_queries`` (default all queries).
            context_padding_mask: optional bool ``(B, T)``, ``True`` = padded token.
            causal: override the encoder's causality for this call.

        Returns:
            ``(B, K, action_dim)``.
        """
        K = self.num_action_queries if num_actions is None else num_actions
        if not isinstance(K, int) or not 1 <= K <= self.num_action_queries:
            raise ValueError(f"num_actions={K!r} must be an int in [1, {self.num_action_queries}]")
        ctx = self.context_proj(as_context_tokens(context, self.context_dim))  # (B, T, D)
        B = ctx.shape[0]
        x = self.queries[:K].unsqueeze(0).expand(B, K, self.hidden_dim)  # (B, K, D)
        if self.pos_embed is not None:
            x = x + self.pos_embed[:K]  # (B, K, D)
        x = self.forward_tokens(x, ctx, context_padding_mask, causal)  # (B, K, D)
        return self.action_head(self.norm(x))  # (B, K, A)

    def forward_tokens(
        self,
        x: torch.Tensor,
        ctx: torch.Tensor,
        context_padding_mask: torch.Tensor | None = None,
        causal: bool | None = None,
    ) -> torch.Tensor:
        """Run the blocks on query tokens (with optional gradient checkpointing).

        Args:
            x: ``(B, K, D)`` query tokens.
            ctx: ``(B, T, D)`` projected context tokens.
            context_padding_mask: optional bool ``(B, T)``.
            causal: causality override.

        Returns:
            ``(B, K, D)``.
        """
        use_ckpt = self.gradient_checkpointing and self.training and torch.is_grad_enabled()
        for block in self.blocks:
            if use_ckpt:
                x = checkpoint(block, x, ctx, context_padding_mask, causal, use_reentrant=False)
            else:
                x = block(x, ctx, context_padding_mask, causal)  # (B, K, D)
        return x
