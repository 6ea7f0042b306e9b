"""``EncodersConfig``: the observation encoders and their token fusion (``model.encoders``).

The encoders' keyword defaults are read from here, so they cannot drift.

Next in the data flow: :mod:`vla_gr.core.encoders.rgbd`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vla_gr.geometry.robot_spec import MAX_DEPTH
from vla_gr.validation import check_choice, check_positive

__all__ = ["TEXT_ENCODERS", "VISION_CHANNELS", "VISION_POOLS", "EncodersConfig"]

VISION_POOLS = ("grid", "spatial_softmax")
TEXT_ENCODERS = ("hashed", "minilm")
VISION_CHANNELS = (32, 64, 64)


@dataclass
class EncodersConfig:
    """RGB-D CNN + instruction encoder + pose MLP -> ``dim``-wide tokens, then fusion blocks."""

    dim: int = 128  # width D of every context token
    vision_channels: list[int] = field(default_factory=lambda: list(VISION_CHANNELS))
    vision_pool: str = "grid"
    vision_tokens: int = 4  # grid: tokens per frame (a square); spatial_softmax: keypoints
    max_depth: float = MAX_DEPTH  # metres; depth is clipped and scaled to [0, 1]
    text_encoder: str = "hashed"
    text_buckets: int = 4096  # hashed bag-of-words vocabulary
    pose_hidden: int = 64
    fusion_layers: int = 1  # transformer blocks over the context tokens (0 = none)
    fusion_heads: int = 4
    dropout: float = 0.0  # fusion blocks
    gradient_checkpointing: bool = False  # vision stages and fusion blocks

    def __post_init__(self) -> None:
        check_positive("model.encoders.dim", self.dim)
        if not self.vision_channels or min(self.vision_channels) < 1:
            raise ValueError(
                f"model.encoders.vision_channels={self.vision_channels} must be a non-empty "
                "list of positive widths"
            )
        check_choice("model.encoders.vision_pool", self.vision_pool, VISION_POOLS)
        check_positive("model.encoders.vision_tokens", self.vision_tokens)
        if self.vision_pool == "grid" and int(self.vision_tokens**0.5) ** 2 != self.vision_tokens:
            raise ValueError(
                f"model.encoders.vision_tokens={self.vision_tokens} must be a square "
                "(1, 4, 9, ...) with model.encoders.vision_pool=grid"
            )
        check_positive("model.encoders.max_depth", self.max_depth)
        check_choice("model.encoders.text_encoder", self.text_encoder, TEXT_ENCODERS)
        check_positive("model.encoders.text_buckets", self.text_buckets)
        check_positive("model.encoders.pose_hidden", self.pose_hidden)
        check_positive("model.encoders.fusion_layers", self.fusion_layers, allow_zero=True)
        check_positive("model.encoders.fusion_heads", self.fusion_heads)
        if self.dim % self.fusion_heads:
            raise ValueError(
                f"model.encoders.dim={self.dim} must be divisible by "
                f"model.encoders.fusion_heads={self.fusion_heads}"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"model.encoders.dropout={self.dropout} must be in [0, 1)")
