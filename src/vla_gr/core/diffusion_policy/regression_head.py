"""OpenVLA-OFT's parallel-decoding L1 regression head (the fast, unimodal baseline).

Shares :class:`~vla_gr.core.diffusion_policy.DiffusionPolicy`'s interface
(``head(actions, context) -> {"loss", ...}``, ``head.get_action(context) -> (B, H, A)``)
and is what ``DiffusionPolicy(objective="l1")`` dispatches to.

Next in the data flow: :mod:`vla_gr.core.trajectory_attention.encoder` (its decoder).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.core.diffusion_policy.config import HeadConfig
from vla_gr.core.trajectory_attention.attention import as_context_tokens
from vla_gr.core.trajectory_attention.encoder import TrajectoryEncoder
from vla_gr.validation import check_positive_int

__all__ = ["L1RegressionHead", "check_actions", "ctx_mask"]


def check_actions(actions: torch.Tensor, horizon: int, action_dim: int) -> None:
    """Raise ValueError unless ``actions`` is ``(B, horizon, action_dim)``."""
    if actions.dim() != 3 or actions.shape[1] != horizon or actions.shape[2] != action_dim:
        raise ValueError(
            f"actions must be (B, {horizon}, {action_dim}) = (B, horizon, action_dim); "
            f"got {tuple(actions.shape)}"
        )


class L1RegressionHead(nn.Module):
    """Parallel-decoding L1 regression head (OpenVLA-OFT).

    ``horizon`` learned action queries attend bidirectionally to each other and to
    the context in one pass (:class:`TrajectoryEncoder`); trained with an L1 loss. A
    regression head cannot represent multi-modal action distributions: on two equally
    likely modes it predicts a point between them.

    Args:
        action_dim: action size ``A``.
        hidden_dim: transformer width ``D``.
        context_dim: context width ``C`` (default ``hidden_dim``).
        horizon: chunk length ``H``.
        num_layers: transformer blocks.
        num_heads: attention heads.
        dropout: dropout probability.
        clip_sample: clip predictions to ``[-1, 1]`` at inference.
        gradient_checkpointing: recompute blocks in backward.
        mlp_ratio: MLP width as a multiple of ``hidden_dim``.
    """

    def __init__(
        self,
        action_dim: int = HeadConfig.action_dim,
        hidden_dim: int = HeadConfig.hidden_dim,
        context_dim: int | None = None,
        horizon: int = HeadConfig.horizon,
        num_layers: int = HeadConfig.num_layers,
        num_heads: int = HeadConfig.num_heads,
        dropout: float = HeadConfig.dropout,
        clip_sample: bool = HeadConfig.clip_sample,
        gradient_checkpointing: bool = HeadConfig.gradient_checkpointing,
        mlp_ratio: float = HeadConfig.mlp_ratio,
    ) -> None:
        super().__init__()
        for name, val in (("action_dim", action_dim), ("hidden_dim", hidden_dim)):
            check_positive_int(name, val)
        check_positive_int("horizon", horizon)
        self.action_dim, self.horizon, self.clip_sample = action_dim, horizon, clip_sample
        self.context_dim = hidden_dim if context_dim is None else context_dim
        self.encoder = TrajectoryEncoder(
            action_dim,
            hidden_dim,
            num_layers,
            horizon,
            use_rope=True,
            num_heads=num_heads,
            causal=False,
            context_dim=self.context_dim,
            mlp_ratio=mlp_ratio,
            dropout=dropout,
            gradient_checkpointing=gradient_checkpointing,
        )

    def forward(
        self,
        actions: torch.Tensor,
        context: torch.Tensor,
        context_padding_mask: torch.Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> dict[str, torch.Tensor]:
        """L1 training loss.

        Args:
            actions: ``(B, H, A)`` target actions.
            context: ``(B, C)`` or ``(B, T, C)``.
            context_padding_mask: optional bool ``(B, T)``.
            generator: unused (interface parity with the generative heads).

        Returns:
            ``{"loss": scalar, "l1": scalar (detached)}``.
        """
        check_actions(actions, self.horizon, self.action_dim)
        ctx = as_context_tokens(context, self.context_dim)  # (B, T, C)
        pred = self.encoder(ctx, self.horizon, ctx_mask(context_padding_mask))  # (B, H, A)
        loss = F.l1_loss(pred, actions)
        return {"loss": loss, "l1": loss.detach()}

    @torch.no_grad()
    def get_action(
        self,
        context: torch.Tensor,
        num_inference_steps: int | None = None,
        sampler: str | None = None,
        generator: torch.Generator | None = None,
        context_padding_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Predict a chunk in one pass (``num_inference_steps``/``sampler`` are ignored).

        Args:
            context: ``(B, C)`` or ``(B, T, C)``.
            num_inference_steps: ignored.
            sampler: ignored.
            generator: ignored.
            context_padding_mask: optional bool ``(B, T)``.

        Returns:
            ``(B, H, A)``.
        """
        ctx = as_context_tokens(context, self.context_dim)  # (B, T, C)
        out = self.encoder(ctx, self.horizon, ctx_mask(context_padding_mask))  # (B, H, A)
        return out.clamp(-1.0, 1.0) if self.clip_sample else out


def ctx_mask(mask: torch.Tensor | None) -> torch.Tensor | None:
    """Bool ``(B, T)`` padding mask (``True`` = padded) or ``None``."""
    return None if mask is None else mask.bool()
