"""S2, the slow planner: vision-language tokens -> latent goal, sub-goals, confidence.

Next in the data flow: :mod:`vla_gr.core.dual_system.controller` (S1 reads the latent goal).
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["S2Planner"]


class S2Planner(nn.Module):
    """Slow planner: vision-language tokens -> latent goal, sub-goals, confidence.

    Learnable query tokens (one goal token, ``num_subgoals`` sub-goal tokens) are
    prepended to the projected input tokens and encoded jointly (pre-norm
    transformer); the goal token feeds the goal and confidence heads.
    """

    def __init__(
        self,
        vlm_dim: int,
        hidden_dim: int,
        goal_dim: int,
        num_subgoals: int = 4,
        num_layers: int = 2,
        num_heads: int = 4,
        dropout: float = 0.0,
    ) -> None:
        super().__init__()
        if hidden_dim % num_heads != 0:
            raise ValueError(
                f"s2_hidden_dim={hidden_dim} must be divisible by s2_num_heads={num_heads}"
            )
        self.num_subgoals = num_subgoals
        self.in_proj = nn.Sequential(nn.LayerNorm(vlm_dim), nn.Linear(vlm_dim, hidden_dim))
        self.queries = nn.Parameter(0.02 * torch.randn(1 + num_subgoals, hidden_dim))
        layer = nn.TransformerEncoderLayer(
            hidden_dim,
            num_heads,
            4 * hidden_dim,
            dropout,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        self.encoder = nn.TransformerEncoder(layer, num_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(hidden_dim)
        self.goal_head = nn.Linear(hidden_dim, goal_dim)
        self.subgoal_head = nn.Linear(hidden_dim, goal_dim) if num_subgoals > 0 else None
        self.confidence_head = nn.Linear(hidden_dim, 1)

    def forward(
        self, vlm_features: torch.Tensor, vlm_mask: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor | None]:
        """Plan.

        Args:
            vlm_features: (B, T, vlm_dim) tokens or (B, vlm_dim) pooled features.
            vlm_mask: optional (B, T) bool, True where a token is valid.

        Returns:
            ``latent_goal`` (B, G), ``subgoals`` (B, K, G) or None, ``confidence``
            (B,) in (0, 1) and ``confidence_logit`` (B,).
        """
        if vlm_features.dim() == 2:
            vlm_features = vlm_features.unsqueeze(1)  # (B, 1, vlm_dim)
        B = vlm_features.shape[0]
        tokens = self.in_proj(vlm_features)  # (B, T, D)
        queries = self.queries.unsqueeze(0).expand(B, -1, -1)  # (B, 1+K, D)
        x = torch.cat([queries, tokens], dim=1)  # (B, 1+K+T, D)
        pad = None
        if vlm_mask is not None:
            valid_q = torch.ones(B, queries.shape[1], dtype=torch.bool, device=x.device)
            pad = ~torch.cat([valid_q, vlm_mask.to(torch.bool)], dim=1)  # (B, 1+K+T)
        x = self.norm(self.encoder(x, src_key_padding_mask=pad))  # (B, 1+K+T, D)
        goal_token = x[:, 0]  # (B, D)
        logit = self.confidence_head(goal_token).squeeze(-1)  # (B,)
        subgoals = None
        if self.subgoal_head is not None:
            subgoals = self.subgoal_head(x[:, 1 : 1 + self.num_subgoals])  # (B, K, G)
        return {
            "latent_goal": self.goal_head(goal_token),  # (B, G)
            "subgoals": subgoals,
            "confidence": torch.sigmoid(logit),  # (B,)
            "confidence_logit": logit,  # (B,)
        }
