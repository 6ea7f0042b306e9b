"""Pose encoder of the agent: ``(x, y, yaw)`` -> ``(x, y, sin yaw, cos yaw)`` -> MLP tokens.

Next in the data flow: the encoders' tokens are fused in :class:`vla_gr.policy.VLAGRPolicy`
and read by the action head (:mod:`vla_gr.core.diffusion_policy`).
"""

from __future__ import annotations

import torch
from torch import nn

from vla_gr.core.encoders.config import EncodersConfig

__all__ = ["pose_features", "PoseEncoder"]


def pose_features(pose: torch.Tensor, scale: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """``(x, y, yaw)`` -> ``(x', y', sin yaw, cos yaw)`` with ``x' = x * scale + offset``.

    Args:
        pose: ``(..., 3)`` raw poses (metres, radians).
        scale: ``(3,)`` min-max normaliser scale (only x, y are used).
        offset: ``(3,)`` min-max normaliser offset.

    Returns:
        ``(..., 4)`` features; yaw goes through sin/cos so that it wraps correctly.
    """
    xy = pose[..., :2] * scale[:2] + offset[:2]  # (..., 2)
    yaw = pose[..., 2:3]  # (..., 1)
    return torch.cat([xy, torch.sin(yaw), torch.cos(yaw)], dim=-1)  # (..., 4)


class PoseEncoder(nn.Module):
    """MLP over pose features ``(..., 4)`` -> ``(..., D)``."""

    def __init__(
        self, dim: int, hidden: int = EncodersConfig.pose_hidden, in_features: int = 4
    ) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_features, hidden), nn.SiLU(), nn.Linear(hidden, dim))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """``features`` ``(..., F)`` -> ``(..., D)``."""
        return self.net(features)
