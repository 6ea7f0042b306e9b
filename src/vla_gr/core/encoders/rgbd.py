"""RGB-D encoder of the agent: a small GroupNorm CNN over RGB + scaled depth -> image tokens.

Pools to a grid of tokens or to spatial-softmax keypoints (diffusion_policy / LeRobot).
Next in the data flow: :mod:`vla_gr.core.encoders.text` (the instruction token).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

from vla_gr.core.encoders.config import VISION_CHANNELS, VISION_POOLS, EncodersConfig
from vla_gr.validation import check_choice

__all__ = ["spatial_softmax", "RGBDEncoder"]


def spatial_softmax(features: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """Expected image coordinates of each channel's softmax (Levine et al. 2016).

    Args:
        features: ``(N, C, H, W)`` feature maps.
        temperature: softmax temperature.

    Returns:
        ``(N, C, 2)`` keypoints ``(x, y)`` in ``[-1, 1]`` (x along W, y along H).
    """
    N, C, H, W = features.shape
    ys = torch.linspace(-1.0, 1.0, H, device=features.device, dtype=features.dtype)  # (H,)
    xs = torch.linspace(-1.0, 1.0, W, device=features.device, dtype=features.dtype)  # (W,)
    grid_y, grid_x = torch.meshgrid(ys, xs, indexing="ij")  # (H, W) each
    coords = torch.stack([grid_x.reshape(-1), grid_y.reshape(-1)], dim=-1)  # (H*W, 2)
    attn = torch.softmax(features.reshape(N, C, H * W) / temperature, dim=-1)  # (N, C, H*W)
    return attn @ coords  # (N, C, 2)


class _Stage(nn.Module):
    """Conv 3x3 stride 2 -> GroupNorm -> SiLU -> conv 3x3 -> GroupNorm -> SiLU."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        groups = max(1, min(8, c_out // 4))
        while c_out % groups:
            groups -= 1
        self.net = nn.Sequential(
            nn.Conv2d(c_in, c_out, 3, stride=2, padding=1),
            nn.GroupNorm(groups, c_out),
            nn.SiLU(),
            nn.Conv2d(c_out, c_out, 3, padding=1),
            nn.GroupNorm(groups, c_out),
            nn.SiLU(),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class RGBDEncoder(nn.Module):
    """Small CNN over RGB-D frames -> ``num_tokens`` tokens of width ``dim`` per frame.

    Args:
        channels: widths of the stride-2 stages (``len(channels)`` halvings).
        dim: token width ``D``.
        pool: ``"grid"`` (average pool to a sqrt(K) x sqrt(K) grid, one token per cell,
            plus a learned position embedding) or ``"spatial_softmax"`` (K keypoints from
            a 1x1 conv, each keypoint ``(x, y)`` embedded as one token).
        num_tokens: ``K``.
        max_depth: depth is clipped to ``[0, max_depth]`` metres and scaled to ``[0, 1]``.
        gradient_checkpointing: recompute stage activations in backward to save memory.
    """

    def __init__(
        self,
        channels: Sequence[int] = VISION_CHANNELS,
        dim: int = EncodersConfig.dim,
        pool: str = EncodersConfig.vision_pool,
        num_tokens: int = EncodersConfig.vision_tokens,
        max_depth: float = EncodersConfig.max_depth,
        gradient_checkpointing: bool = EncodersConfig.gradient_checkpointing,
    ) -> None:
        super().__init__()
        check_choice("pool", pool, VISION_POOLS)
        if not channels:
            raise ValueError("channels must name at least one stage width")
        self.pool, self.num_tokens, self.max_depth = pool, num_tokens, max_depth
        self.gradient_checkpointing = gradient_checkpointing
        widths = [4, *channels]
        self.stages = nn.ModuleList(_Stage(a, b) for a, b in zip(widths[:-1], widths[1:]))
        c = channels[-1]
        if pool == "grid":
            side = int(round(num_tokens**0.5))
            if side * side != num_tokens:
                raise ValueError(f"num_tokens={num_tokens} must be a square for pool='grid'")
            self.side = side
            self.proj = nn.Linear(c, dim)
            self.pos = nn.Parameter(torch.zeros(num_tokens, dim))
        else:
            self.keypoints = nn.Conv2d(c, num_tokens, 1)
            self.proj = nn.Linear(2, dim)
            self.pos = nn.Parameter(torch.zeros(num_tokens, dim))
        nn.init.normal_(self.pos, std=0.02)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Encode frames.

        Args:
            rgb: ``(N, 3, H, W)`` float in ``[0, 1]`` or uint8.
            depth: ``(N, 1, H, W)`` metres.

        Returns:
            ``(N, K, D)`` tokens.
        """
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (N, 3, H, W); got {tuple(rgb.shape)}")
        if depth.shape != (rgb.shape[0], 1, *rgb.shape[2:]):
            raise ValueError(f"depth must be (N, 1, H, W) like rgb; got {tuple(depth.shape)}")
        if rgb.dtype == torch.uint8:
            rgb = rgb.float() / 255.0
        d = depth.float().clamp(0.0, self.max_depth) / self.max_depth  # (N, 1, H, W)
        x = torch.cat([rgb.float() * 2.0 - 1.0, d * 2.0 - 1.0], dim=1)  # (N, 4, H, W)
        for stage in self.stages:
            if self.gradient_checkpointing and self.training and x.requires_grad:
                x = checkpoint(stage, x, use_reentrant=False)
            else:
                x = stage(x)  # (N, C_i, H_i, W_i)
        if self.pool == "grid":
            x = F.adaptive_avg_pool2d(x, self.side)  # (N, C, s, s)
            tokens = self.proj(x.flatten(2).transpose(1, 2))  # (N, K, D)
        else:
            kp = spatial_softmax(self.keypoints(x))  # (N, K, 2)
            tokens = self.proj(kp)  # (N, K, D)
        return tokens + self.pos  # (N, K, D)
