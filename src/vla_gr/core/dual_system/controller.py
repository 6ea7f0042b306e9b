"""S1, the fast reactive controller: visual features + proprioception + latest goal -> action.

Next in the data flow: :mod:`vla_gr.core.dual_system.architecture` (schedules S2 and S1).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.core.dual_system.config import GATES
from vla_gr.validation import check_choice

__all__ = ["S1Controller", "gate_actions"]


def gate_actions(
    goal_action: torch.Tensor, reactive_action: torch.Tensor, gate: torch.Tensor
) -> torch.Tensor:
    """Convex blend ``g * goal + (1 - g) * reactive``.

    Args:
        goal_action: (B, A) goal-directed action.
        reactive_action: (B, A) reactive action.
        gate: (B,) weight in [0, 1] of the goal-directed branch.

    Returns:
        (B, A) blended action.
    """
    g = gate.unsqueeze(-1)  # (B, 1)
    return g * goal_action + (1.0 - g) * reactive_action  # (B, A)


class _ResidualMLPBlock(nn.Module):
    """Pre-norm residual MLP block ``x + W2 gelu(W1 norm(x))``."""

    def __init__(self, dim: int, expansion: int = 2, dropout: float = 0.0) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.fc1 = nn.Linear(dim, expansion * dim)
        self.fc2 = nn.Linear(expansion * dim, dim)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, D) -> (B, D)."""
        return x + self.dropout(self.fc2(F.gelu(self.fc1(self.norm(x)))))  # (B, D)


def _head(dim: int, out_dim: int) -> nn.Sequential:
    return nn.Sequential(nn.LayerNorm(dim), nn.Linear(dim, dim), nn.GELU(), nn.Linear(dim, out_dim))


class S1Controller(nn.Module):
    """Fast controller: (visual, proprioception, latent goal, confidence) -> action.

    A shared residual-MLP trunk encodes the current observation; a *reactive*
    head maps it to an action directly, a *goal-directed* head maps the trunk
    state FiLM-modulated by the latent goal. The two are blended by the S2
    confidence (``gate="confidence"``) or by a learned correction of its logit
    from the S1 state (``gate="learned"``, zero-initialised so it starts equal).
    """

    def __init__(
        self,
        visual_dim: int,
        proprio_dim: int,
        goal_dim: int,
        hidden_dim: int,
        action_dim: int,
        num_layers: int = 2,
        gate: str = "confidence",
        dropout: float = 0.0,
    ) -> None:
        super().__init__()
        check_choice("gate", gate, GATES)
        self.gate = gate
        self.visual_proj = nn.Sequential(
            nn.LayerNorm(visual_dim), nn.Linear(visual_dim, hidden_dim)
        )
        self.proprio_proj = nn.Linear(proprio_dim, hidden_dim)
        self.trunk = nn.Sequential(
            *[_ResidualMLPBlock(hidden_dim, dropout=dropout) for _ in range(num_layers)]
        )
        self.goal_film = nn.Linear(goal_dim, 2 * hidden_dim)
        self.reactive_head = _head(hidden_dim, action_dim)
        self.goal_head = _head(hidden_dim, action_dim)
        self.gate_adjust = None
        if gate == "learned":
            self.gate_adjust = nn.Linear(hidden_dim, 1)
            nn.init.zeros_(self.gate_adjust.weight)
            nn.init.zeros_(self.gate_adjust.bias)

    def forward(
        self,
        visual_features: torch.Tensor,
        proprioception: torch.Tensor,
        latent_goal: torch.Tensor,
        confidence: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """Act.

        Args:
            visual_features: (B, V) or (B, T, V) tokens (mean-pooled).
            proprioception: (B, P).
            latent_goal: (B, G) latest S2 goal.
            confidence: (B,) S2 confidence in [0, 1].

        Returns:
            ``action`` (B, A), ``goal_action`` (B, A), ``reactive_action`` (B, A),
            ``gate`` (B,) weight actually given to the goal-directed branch.
        """
        if visual_features.dim() == 3:
            visual_features = visual_features.mean(dim=1)  # (B, V)
        h = self.visual_proj(visual_features) + self.proprio_proj(proprioception)  # (B, D)
        h = self.trunk(h)  # (B, D)
        gamma, beta = self.goal_film(latent_goal).chunk(2, dim=-1)  # (B, D) each
        h_goal = h * (1.0 + gamma) + beta  # (B, D)
        goal_action = self.goal_head(h_goal)  # (B, A)
        reactive_action = self.reactive_head(h)  # (B, A)
        gate = confidence  # (B,)
        if self.gate_adjust is not None:
            eps = 1e-6
            logit = torch.logit(confidence.clamp(eps, 1.0 - eps))  # (B,)
            gate = torch.sigmoid(logit + self.gate_adjust(h).squeeze(-1))  # (B,)
        return {
            "action": gate_actions(goal_action, reactive_action, gate),  # (B, A)
            "goal_action": goal_action,
            "reactive_action": reactive_action,
            "gate": gate,
        }
