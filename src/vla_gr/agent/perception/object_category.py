"""Which object category each pixel shows, and S2's check that a goal is of the instructed one.

The goal head marks the object an instruction means from one frame. When it is wrong, it
often marks an object of another category: the anchor of a relation ("the chair near the
*plant*"), or a piece of the instructed colour. Near a confirmed goal, the navigator asks how
likely the pixels the goal head marks are of the instructed category; a confident "no" rejects
that goal and exploration goes on (``navigator.goal_checks.object_reject_threshold``).

- :class:`ObjectCategorySegmenter`: one RGB-D frame -> per-pixel logits over background and
  ``categories``. A small encoder-decoder, trained on labels from the world's geometry
  (:mod:`vla_gr.training.object_category`).
- :func:`instructed_category`: the category an instruction names ("the red chair ..."); None
  when it names none of them, and the check stays off for that episode.
- :func:`category_match`: mean probability of a category over a goal mask.
- :func:`instructed_anchor`: the category a relation names ("... near the plant" -> plant);
  its per-pixel probability lets the navigator map the anchor and check that the goal it
  stands at has one near (``navigator.goal_checks.relation_distance``).
- :class:`ObjectEvidence`: what one S2 tick hands the navigator.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.agent.perception.engine import Network
from vla_gr.agent.perception.goal_head import norm_groups, rgbd_inputs
from vla_gr.geometry.robot_spec import MAX_DEPTH
from vla_gr.validation import check_positive

__all__ = [
    "ObjectCategoryConfig",
    "ObjectEvidence",
    "ObjectCategorySegmenter",
    "category_match",
    "instructed_anchor",
    "instructed_category",
    "spoken_name",
]


#: The world's object categories, in the order of the segmenter's classes (after background).
CATEGORIES: tuple[str, ...] = (
    "chair", "sofa", "bed", "toilet", "tv_monitor", "plant", "table", "cabinet",
)  # fmt: skip


@dataclass
class ObjectCategoryConfig:
    """The object-category segmenter (``model.object_category.*``); weights in the checkpoint."""

    # build it (S2 uses it with navigator.goal_checks.object_reject_threshold)
    enabled: bool = False
    categories: list[str] = field(default_factory=lambda: list(CATEGORIES))
    channels: list[int] = field(default_factory=lambda: [16, 32, 64])  # stride-2 stages
    max_depth: float = MAX_DEPTH  # metres; depth is clipped and scaled to [-1, 1]
    min_goal_pixels: int = 4  # fewer goal pixels in a frame give no evidence
    # a relation without a colour ("the chair near the plant"): every pixel of the instructed
    # category is a goal candidate too (the goal likelihood is the larger of the goal head's
    # and the segmenter's), and the navigator's relation check picks among them
    relation_candidates: bool = False
    # a relation ("the chair near the table"): pixels the segmenter reads as the anchor are
    # not goal pixels, whatever the goal head says (it often marks the anchor too)
    anchor_not_goal: bool = False

    def __post_init__(self) -> None:
        if not self.categories or len(set(self.categories)) != len(self.categories):
            raise ValueError(
                f"model.object_category.categories={self.categories} must name distinct categories"
            )
        if len(self.channels) < 2 or min(self.channels) < 1:
            raise ValueError(
                f"model.object_category.channels={self.channels} must be two or more positive "
                "widths"
            )
        check_positive("model.object_category.max_depth", self.max_depth)
        check_positive("model.object_category.min_goal_pixels", self.min_goal_pixels)


class ObjectEvidence(NamedTuple):
    """One S2 tick's object evidence: ``match`` = probability that the goal pixels show the
    instructed category (None: no evidence); ``anchor`` = (H, W) probability of the relation's
    anchor category (None: the instruction names no relation)."""

    match: float | None = None
    anchor: np.ndarray | None = None


def _block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=1),
        nn.GroupNorm(norm_groups(cout), cout),
        nn.SiLU(),
    )


class ObjectCategorySegmenter(nn.Module):
    """RGB-D frame -> logits (B, 1 + K, H, W) over background and the K ``categories``.

    Encoder: (conv 3x3 stride 2 -> GroupNorm -> SiLU) per width in ``channels``; decoder:
    upsample x2, concatenate the encoder's map of that size, conv; the logits of the
    half-resolution map are upsampled bilinearly to the input size.
    """

    def __init__(self, config: ObjectCategoryConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or ObjectCategoryConfig()
        widths = list(c.channels)
        self.down = nn.ModuleList()
        cin = 4
        for w in widths:
            self.down.append(_block(cin, w, stride=2))
            cin = w
        self.bottleneck = _block(cin, cin)
        self.up = nn.ModuleList()
        for skip in reversed(widths[:-1]):
            self.up.append(_block(cin + skip, skip))
            cin = skip
        self.logits = nn.Conv2d(cin, 1 + len(c.categories), 1)

    def network_inputs(self, rgb: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor]:
        """What :meth:`network` takes: rgb (B, 3, H, W) uint8 or [0, 1], depth (B, 1, H, W)
        metres -> (x (B, 4, H, W) in [-1, 1],)."""
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (B, 3, H, W); got {tuple(rgb.shape)}")
        if depth.shape != (rgb.shape[0], 1, *rgb.shape[2:]):
            raise ValueError(f"depth must be (B, 1, H, W) like rgb; got {tuple(depth.shape)}")
        return (rgbd_inputs(rgb, depth, self.config.max_depth),)  # (B, 4, H, W)

    def network(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        """The encoder-decoder, what an inference engine runs (:mod:`.engine`): x (B, 4, H, W)
        in [-1, 1] -> ``logits`` (B, 1 + K, H, W)."""
        size = x.shape[-2:]
        skips = []
        for block in self.down:
            x = block(x)  # (B, C_i, H / 2^i, W / 2^i)
            skips.append(x)
        x = self.bottleneck(skips.pop())  # (B, C_last, h, w)
        for block in self.up:
            skip = skips.pop()  # (B, C_s, 2h, 2w)
            x = F.interpolate(x, size=skip.shape[-2:], mode="nearest")  # (B, C, 2h, 2w)
            x = block(torch.cat([x, skip], dim=1))  # (B, C_s, 2h, 2w)
        logits = self.logits(x)  # (B, 1 + K, H / 2, W / 2)
        logits = F.interpolate(logits, size=size, mode="bilinear", align_corners=False)
        return {"logits": logits}  # (B, 1 + K, H, W)

    def forward(
        self, rgb: torch.Tensor, depth: torch.Tensor, network: Network | None = None
    ) -> torch.Tensor:
        """rgb (B, 3, H, W) uint8 or [0, 1], depth (B, 1, H, W) metres -> (B, 1 + K, H, W);
        ``network`` runs :meth:`network` (an engine's export of it; None: this module)."""
        return (network or self.network)(*self.network_inputs(rgb, depth))["logits"]

    @torch.no_grad()
    def probabilities(
        self, rgb: torch.Tensor, depth: torch.Tensor, network: Network | None = None
    ) -> torch.Tensor:
        """Per-pixel probabilities (B, 1 + K, H, W): background, then ``config.categories``."""
        return F.softmax(self(rgb, depth, network).float(), dim=1)


def category_match(
    probabilities: np.ndarray, goal: np.ndarray, category: int, min_pixels: int = 1
) -> float | None:
    """Mean probability of class ``category`` (1-based: 0 is background) over the ``goal``
    pixels (H, W) bool of one frame's ``probabilities`` (1 + K, H, W); None with fewer than
    ``min_pixels`` goal pixels (no evidence this frame)."""
    goal = np.asarray(goal, bool)
    if probabilities.shape[1:] != goal.shape:
        raise ValueError(
            f"goal mask {goal.shape} and probabilities {probabilities.shape} differ in size"
        )
    if int(goal.sum()) < max(1, min_pixels):
        return None
    return float(probabilities[category][goal].mean())


def spoken_name(category: str) -> str:
    """How instructions say a category: 'tv_monitor' -> 'tv', 'potted_plant' -> 'potted plant'."""
    return {"tv_monitor": "tv"}.get(category, category.replace("_", " "))


@lru_cache(maxsize=64)
def _category_pattern(categories: tuple[str, ...]) -> re.Pattern:
    names = sorted(map(spoken_name, categories), key=len, reverse=True)
    return re.compile(r"\b(" + "|".join(map(re.escape, names)) + r")\b", re.IGNORECASE)


_RELATION = re.compile(r"\b(?:next to|near|beside|by)\b", re.IGNORECASE)


def _named_category(text: str, categories: tuple[str, ...] | list[str]) -> int | None:
    """1-based class index of the first of ``categories`` that ``text`` names, or None."""
    found = _category_pattern(tuple(categories)).search(text)
    if found is None:
        return None
    return [spoken_name(c) for c in categories].index(found.group(1).lower()) + 1


def _split_relation(instruction: str) -> tuple[str, str | None]:
    """(the words before the first relation word, those after it or None without one)."""
    if not isinstance(instruction, str):
        raise TypeError(f"instruction must be a str, got {type(instruction).__name__}")
    relation = _RELATION.search(instruction)
    if relation is None:
        return instruction, None
    return instruction[: relation.start()], instruction[relation.end() :]


def instructed_category(instruction: str, categories: tuple[str, ...] | list[str]) -> int | None:
    """1-based class index (as in :func:`category_match`) of the first category
    ``instruction`` names before any relation word ("the chair near the plant" -> chair),
    or None when it names none of ``categories`` there."""
    return _named_category(_split_relation(instruction)[0], categories)


def instructed_anchor(instruction: str, categories: tuple[str, ...] | list[str]) -> int | None:
    """1-based class index of the category right after the relation word ("the chair near
    the plant" -> plant); None without a relation or when it names none of ``categories``."""
    tail = _split_relation(instruction)[1]
    if tail is None:
        return None
    found = re.match(r"\s*(?:the\s+)?(\w+(?:\s\w+)?)", tail)
    return None if found is None else _named_category(found.group(0), categories)
