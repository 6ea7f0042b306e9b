"""The language-grounded goal head: which pixels show THE object the instruction means.

S2's perception. Input: one RGB-D frame and the instruction; output: a per-pixel logit that
the pixel belongs to the goal instance (not any object of its category: the same-category
distractors are negatives) and a per-frame logit that the goal is visible at all. With
``category_head`` it also gives a per-pixel logit that the pixel shows an object of the
instructed *category* (the goal or any same-category distractor); the instance probability S2
uses is then the product of the two, so the instance output only has to pick among objects of
the right category.

Architecture: a small U-Net (stride-2 encoder, nearest-upsampling decoder with skips) whose
every stage is FiLM-conditioned on the instruction embedding (the frozen MiniLM sentence
encoder by default, or the hashed bag of words). The per-pixel likelihood feeds the GR field
(:mod:`vla_gr.core.gr_field`); losses and metrics are in :mod:`.losses`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

from vla_gr.agent.perception.engine import Network
from vla_gr.core.encoders import TEXT_ENCODERS, build_text_encoder
from vla_gr.geometry.robot_spec import MAX_DEPTH
from vla_gr.validation import check_choice, check_positive

__all__ = ["GoalHead", "GoalHeadConfig", "rgbd_inputs", "upsample_nearest_2x"]


@dataclass
class GoalHeadConfig:
    """Sizes of the goal head (``model.goal_head.*``)."""

    channels: list[int] = field(default_factory=lambda: [32, 64, 96])  # encoder stage widths
    stem_channels: int = 16  # full-resolution features kept for the last skip
    text_encoder: str = "minilm"
    text_dim: int = 128  # width of the projected instruction embedding
    text_buckets: int = 4096  # hashed encoder vocabulary
    max_depth: float = MAX_DEPTH  # metres; depth is clipped and scaled to [-1, 1]
    category_head: bool = False  # second per-pixel output: "shows the instructed category"
    category_gate: bool = True  # inference: false = the instance output alone (an ablation)
    test_time_flip: bool = False  # inference: average with the mirrored frame (2 passes)

    def __post_init__(self) -> None:
        if not self.channels or min(self.channels) < 1:
            raise ValueError(f"model.goal_head.channels={self.channels} must be positive widths")
        check_choice("model.goal_head.text_encoder", self.text_encoder, TEXT_ENCODERS)
        if not self.category_gate and not self.category_head:
            raise ValueError(
                "model.goal_head.category_gate=false switches off a category output this head "
                "does not have (model.goal_head.category_head=false)"
            )
        for key in ("stem_channels", "text_dim", "text_buckets", "max_depth"):
            check_positive(f"model.goal_head.{key}", getattr(self, key))


def norm_groups(channels: int) -> int:
    """GroupNorm groups for ``channels``: up to 8, about 4 channels each, dividing evenly."""
    g = max(1, min(8, channels // 4))
    while channels % g:
        g -= 1
    return g


def rgbd_inputs(rgb: torch.Tensor, depth: torch.Tensor, max_depth: float) -> torch.Tensor:
    """rgb (B, 3, H, W) uint8 or [0, 1] and depth (B, 1, H, W) metres -> (B, 4, H, W) in
    [-1, 1], depth clipped to ``max_depth``."""
    if rgb.dtype == torch.uint8:
        rgb = rgb.float() / 255.0
    d = depth.float().clamp(0.0, max_depth) / max_depth  # (B, 1, H, W)
    return torch.cat([rgb.float() * 2.0 - 1.0, d * 2.0 - 1.0], dim=1)  # (B, 4, H, W)


def upsample_nearest_2x(h: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) -> (B, C, 2H, 2W), each value repeated into a 2x2 block.

    The same values as ``F.interpolate(h, scale_factor=2, mode="nearest")``, as a view
    expanded and copied once: several times faster on CPU at the decoder's sizes. An ONNX
    export writes the interpolation (one Resize: ONNX Runtime runs the Expand 10x slower).
    """
    if torch.onnx.is_in_onnx_export():
        return F.interpolate(h, scale_factor=2.0, mode="nearest")  # (B, C, 2H, 2W)
    B, C, H, W = h.shape
    return h[:, :, :, None, :, None].expand(B, C, H, 2, W, 2).reshape(B, C, 2 * H, 2 * W)


def _mean_with_mirror(v: torch.Tensor) -> torch.Tensor:
    """(2B, ...) outputs of B frames then their mirrors -> (B, ...) mean, the mirrored maps
    (B, H, W) flipped back first; per-frame values (B,) are averaged as they are."""
    own, mirrored = v.chunk(2)  # (B, ...) each
    if mirrored.dim() > 1:
        mirrored = mirrored.flip(-1)
    return 0.5 * (own + mirrored)


class _FiLMConv(nn.Module):
    """conv 3x3 (stride s) -> GroupNorm -> FiLM(text) -> SiLU -> conv 3x3 -> GroupNorm -> SiLU."""

    def __init__(self, c_in: int, c_out: int, text_dim: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)
        self.norm1 = nn.GroupNorm(norm_groups(c_out), c_out)
        self.film = nn.Linear(text_dim, 2 * c_out)
        nn.init.zeros_(self.film.weight)
        nn.init.zeros_(self.film.bias)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1)
        self.norm2 = nn.GroupNorm(norm_groups(c_out), c_out)

    def forward(self, x: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
        """x (B, C_in, H, W), text (B, E) -> (B, C_out, H / s, W / s)."""
        h = self.norm1(self.conv1(x))  # (B, C, H', W')
        gamma, beta = self.film(text)[:, :, None, None].chunk(2, dim=1)  # (B, C, 1, 1) each
        h = F.silu(h * (1.0 + gamma) + beta)  # (B, C, H', W')
        return F.silu(self.norm2(self.conv2(h)))  # (B, C, H', W')


class GoalHead(nn.Module):
    """Per-pixel goal-instance logits and a per-frame visibility logit (see module docstring)."""

    def __init__(self, config: GoalHeadConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or GoalHeadConfig()
        self.text = build_text_encoder(c.text_encoder, c.text_dim, c.text_buckets)
        self.stem = _FiLMConv(4, c.stem_channels, c.text_dim)
        widths = [c.stem_channels, *c.channels]
        self.down = nn.ModuleList(
            _FiLMConv(a, b, c.text_dim, stride=2) for a, b in zip(widths[:-1], widths[1:])
        )
        # decoder stage i merges the upsampled deeper map with the encoder skip at its scale
        self.up = nn.ModuleList(
            _FiLMConv(widths[i + 1] + widths[i], widths[i], c.text_dim)
            for i in reversed(range(len(c.channels)))
        )
        self.pixel_logit = nn.Conv2d(c.stem_channels, 1, 1)
        self.category_logit = nn.Conv2d(c.stem_channels, 1, 1) if c.category_head else None
        self.visible_logit = nn.Sequential(
            nn.Linear(2 * widths[-1], widths[-1]), nn.SiLU(), nn.Linear(widths[-1], 1)
        )
        # training only (``training.gradient_checkpointing``): recompute each stage in backward
        self.gradient_checkpointing = False

    @property
    def stride(self) -> int:
        """Input sides must be divisible by this (one halving per encoder stage)."""
        return 2 ** len(self.config.channels)

    def encode_text(self, instructions: Sequence[str]) -> torch.Tensor:
        """``B`` instructions -> (B, E)."""
        if isinstance(instructions, str) or not all(isinstance(t, str) for t in instructions):
            raise TypeError("instructions must be a sequence of str, one per frame")
        return self.text(list(instructions))  # (B, E)

    def network_inputs(
        self, rgb: torch.Tensor, depth: torch.Tensor, instructions: Sequence[str]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """What :meth:`network` takes: rgb (B, 3, H, W) uint8 or [0, 1], depth (B, 1, H, W) m
        and ``B`` instructions -> x (B, 4, H, W) in [-1, 1] and the instructions' text (B, E)."""
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (B, 3, H, W); got {tuple(rgb.shape)}")
        if depth.shape != (rgb.shape[0], 1, *rgb.shape[2:]):
            raise ValueError(f"depth must be (B, 1, H, W) like rgb; got {tuple(depth.shape)}")
        H, W = rgb.shape[2:]
        if H % self.stride or W % self.stride:
            raise ValueError(f"image sides {(H, W)} must be divisible by {self.stride}")
        x = rgbd_inputs(rgb, depth, self.config.max_depth)  # (B, 4, H, W)
        text = self.encode_text(instructions)  # (B, E)
        if text.shape[0] != x.shape[0]:
            raise ValueError(f"{text.shape[0]} instructions for {x.shape[0]} frames")
        return x, text.to(x.dtype)

    def network(self, x: torch.Tensor, text: torch.Tensor) -> dict[str, torch.Tensor]:
        """The U-Net, what an inference engine runs (:mod:`.engine`): x (B, 4, H, W) in
        [-1, 1] and text (B, E) (:meth:`network_inputs`) -> the logits of :meth:`forward`."""
        skips = [self._run(self.stem, x, text)]  # [(B, C0, H, W)]
        for stage in self.down:
            skips.append(self._run(stage, skips[-1], text))  # (B, C_i, H / 2^i, W / 2^i)
        h = skips.pop()  # (B, C_last, H / s, W / s)
        pooled = torch.cat([h.mean(dim=(2, 3)), h.amax(dim=(2, 3))], dim=1)  # (B, 2 C_last)
        for stage in self.up:
            skip = skips.pop()  # (B, C_i, 2h, 2w)
            h = upsample_nearest_2x(h)  # (B, C_{i+1}, 2h, 2w): sides divide by the stride
            h = self._run(stage, torch.cat([h, skip], dim=1), text)  # (B, C_i, 2h, 2w)
        out = {
            "pixel_logits": self.pixel_logit(h)[:, 0],  # (B, H, W)
            "visible_logits": self.visible_logit(pooled)[:, 0],  # (B,)
        }
        if self.category_logit is not None:
            out["category_logits"] = self.category_logit(h)[:, 0]  # (B, H, W)
        return out

    def _run(self, stage: nn.Module, x: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
        """``stage(x, text)``, its activations recomputed in backward when training with
        ``gradient_checkpointing`` (the same outputs and gradients, less memory)."""
        if self.gradient_checkpointing and self.training and torch.is_grad_enabled():
            return checkpoint(stage, x, text, use_reentrant=False)
        return stage(x, text)

    def forward(
        self,
        rgb: torch.Tensor,
        depth: torch.Tensor,
        instructions: Sequence[str],
        network: Network | None = None,
    ) -> dict[str, torch.Tensor]:
        """Goal logits of ``B`` frames.

        Args:
            rgb: (B, 3, H, W) uint8 or float in [0, 1].
            depth: (B, 1, H, W) metres.
            instructions: ``B`` strings.
            network: what runs :meth:`network` (an engine's export of it; None: this module).

        Returns:
            ``pixel_logits`` (B, H, W) and ``visible_logits`` (B,); with ``category_head``
            also ``category_logits`` (B, H, W).
        """
        return (network or self.network)(*self.network_inputs(rgb, depth, instructions))

    def pixel_probability(self, outputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """(B, H, W) probability that a pixel shows the goal instance: the instance output,
        gated by the category output when the head has one (and ``category_gate`` is on)."""
        p = torch.sigmoid(outputs["pixel_logits"].float())  # (B, H, W)
        if "category_logits" in outputs and self.config.category_gate:
            p = p * torch.sigmoid(outputs["category_logits"].float())  # (B, H, W)
        return p

    @torch.no_grad()
    def probabilities(
        self,
        rgb: torch.Tensor,
        depth: torch.Tensor,
        instructions: Sequence[str],
        network: Network | None = None,
    ) -> dict[str, torch.Tensor]:
        """``pixel`` (B, H, W) goal-instance probability (gated, as S2 uses it), ``visible``
        (B,) and, with a category output, ``category`` (B, H, W); ``network`` as in
        :meth:`forward`.

        With ``test_time_flip`` each is the mean over the frame and its left-right mirror
        (the mirrored maps flipped back); both go through the network as one batch of 2B.
        """
        flip = self.config.test_time_flip
        if flip:
            rgb = torch.cat([rgb, rgb.flip(-1)])  # (2B, 3, H, W)
            depth = torch.cat([depth, depth.flip(-1)])  # (2B, 1, H, W)
            instructions = [*instructions, *instructions]
        out = self.forward(rgb, depth, instructions, network)
        probs = {
            "pixel": self.pixel_probability(out),  # (B or 2B, H, W)
            "visible": torch.sigmoid(out["visible_logits"].float()),  # (B or 2B,)
        }
        if "category_logits" in out:
            probs["category"] = torch.sigmoid(out["category_logits"].float())  # (B or 2B, H, W)
        if flip:  # the mirrored half back to the frame's own left and right, then the mean
            probs = {k: _mean_with_mirror(v) for k, v in probs.items()}
        return probs

    def likelihood(
        self,
        rgb: torch.Tensor,
        depth: torch.Tensor,
        instructions: Sequence[str],
        network: Network | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Probabilities: per pixel (B, H, W) and goal visible per frame (B,) (see
        :meth:`probabilities`)."""
        probs = self.probabilities(rgb, depth, instructions, network)
        return probs["pixel"], probs["visible"]
