"""Losses and metrics of the goal head (pure functions; :mod:`.goal_head` is the model).

Targets are the goal instance's mask only, so a pixel of a same-category distractor is a
negative like the floor. The optional category output's target is the goal's mask together
with its same-category distractors' masks. A frame counts as "goal visible" when the goal
covers at least ``min_pixels`` pixels (the same threshold as the evaluation's failure causes).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from vla_gr.validation import check_positive

__all__ = [
    "GroundingConfig",
    "goal_head_loss",
    "mask_confusion",
    "confusion_metrics",
    "visible_targets",
]


@dataclass
class GroundingConfig:
    """Loss weights and thresholds of the goal head (``model.grounding.*``)."""

    min_pixels: int = 4  # goal pixels for a frame to count as "goal visible"
    pos_weight: float = 4.0  # weight of goal pixels in the BCE (they are rare)
    dice_weight: float = 1.0
    visible_weight: float = 0.5
    category_weight: float = 1.0  # weight of the category output's BCE + Dice (if the head has it)
    threshold: float = 0.5  # probability above which a pixel / frame is predicted goal

    def __post_init__(self) -> None:
        for key in ("min_pixels", "pos_weight"):
            check_positive(f"model.grounding.{key}", getattr(self, key))
        for key in ("dice_weight", "visible_weight", "category_weight"):
            check_positive(f"model.grounding.{key}", getattr(self, key), allow_zero=True)
        if not 0.0 < self.threshold < 1.0:
            raise ValueError(f"model.grounding.threshold={self.threshold} must be in (0, 1)")


_DEFAULT = GroundingConfig()


def visible_targets(target: torch.Tensor, min_pixels: int) -> torch.Tensor:
    """(B, H, W) bool goal masks -> (B,) float: 1 where the goal covers >= ``min_pixels``."""
    return (target.flatten(1).sum(dim=1) >= min_pixels).float()  # (B,)


def _mask_terms(
    logits: torch.Tensor, target: torch.Tensor, pos_weight: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Weighted BCE over all pixels and soft Dice over the frames whose target is not empty.

    logits (B, H, W), target (B, H, W) bool -> (bce, dice) scalars.
    """
    if logits.shape != target.shape:
        raise ValueError(f"logits {tuple(logits.shape)} and target {tuple(target.shape)} differ")
    t = target.float()  # (B, H, W)
    weight = torch.tensor(pos_weight, dtype=logits.dtype, device=logits.device)
    bce = F.binary_cross_entropy_with_logits(logits, t, pos_weight=weight)
    p = torch.sigmoid(logits).flatten(1)  # (B, H*W)
    inter = (p * t.flatten(1)).sum(dim=1)  # (B,)
    dice_per = 1.0 - (2.0 * inter + 1.0) / (p.sum(dim=1) + t.flatten(1).sum(dim=1) + 1.0)  # (B,)
    shown = target.flatten(1).any(dim=1).float()  # (B,)
    dice = (dice_per * shown).sum() / shown.sum().clamp(min=1.0)
    return bce, dice


def goal_head_loss(
    pixel_logits: torch.Tensor,
    visible_logits: torch.Tensor,
    target: torch.Tensor,
    min_pixels: int = _DEFAULT.min_pixels,
    pos_weight: float = _DEFAULT.pos_weight,
    dice_weight: float = _DEFAULT.dice_weight,
    visible_weight: float = _DEFAULT.visible_weight,
    category_logits: torch.Tensor | None = None,
    category_target: torch.Tensor | None = None,
    category_weight: float = _DEFAULT.category_weight,
) -> dict[str, torch.Tensor]:
    """Weighted BCE per pixel + soft Dice on frames showing the goal + BCE on visibility
    (+ ``category_weight`` x the same BCE + Dice on the category output, when given).

    Args:
        pixel_logits: (B, H, W).
        visible_logits: (B,).
        target: (B, H, W) bool, the goal instance's pixels.
        min_pixels: goal pixels for a frame to count as "goal visible".
        pos_weight: weight of goal pixels in the BCE (they are rare).
        dice_weight, visible_weight: weights of the Dice and visibility terms.
        category_logits: (B, H, W) logits of the category output, or None.
        category_target: (B, H, W) bool, every instance of the instructed category.
        category_weight: weight of the category terms.

    Returns:
        ``loss`` (scalar) and its parts ``pixel_bce``, ``dice``, ``visible_bce`` (and
        ``category_bce``, ``category_dice`` with a category output).
    """
    pixel_bce, dice = _mask_terms(pixel_logits, target, pos_weight)
    visible = visible_targets(target, min_pixels)  # (B,)
    visible_bce = F.binary_cross_entropy_with_logits(visible_logits, visible)
    loss = pixel_bce + dice_weight * dice + visible_weight * visible_bce
    parts = {"pixel_bce": pixel_bce, "dice": dice, "visible_bce": visible_bce}
    if (category_logits is None) != (category_target is None):
        raise ValueError("category_logits and category_target go together")
    if category_logits is not None:
        if (target.bool() & ~category_target.bool()).any():
            raise ValueError("category_target must cover the goal mask (goal | distractors)")
        category_bce, category_dice = _mask_terms(category_logits, category_target, pos_weight)
        loss = loss + category_weight * (category_bce + dice_weight * category_dice)
        parts |= {"category_bce": category_bce, "category_dice": category_dice}
    return {"loss": loss, **parts}


def mask_confusion(
    pixel_prob: torch.Tensor,
    visible_prob: torch.Tensor,
    target: torch.Tensor,
    threshold: float = _DEFAULT.threshold,
    min_pixels: int = _DEFAULT.min_pixels,
    distractors: torch.Tensor | None = None,
) -> dict[str, int]:
    """Counts for precision / recall / accuracy, to be summed over batches.

    Args:
        pixel_prob: (B, H, W) per-pixel goal probability.
        visible_prob: (B,) per-frame goal-visible probability.
        target: (B, H, W) bool goal masks.
        distractors: (B, H, W) bool masks of the goal's same-category distractors, or None.

    Returns:
        pixel ``tp``, ``fp``, ``fn`` and frame ``frames``, ``frames_correct``,
        ``frames_visible`` (ints); with ``distractors`` also ``fp_distractor``, the
        predicted goal pixels that lie on a distractor.
    """
    pred = pixel_prob >= threshold  # (B, H, W)
    tgt = target.bool()
    visible = visible_targets(tgt, min_pixels).bool()  # (B,)
    frame_pred = visible_prob >= threshold  # (B,)
    counts = {
        "tp": int((pred & tgt).sum()),
        "fp": int((pred & ~tgt).sum()),
        "fn": int((~pred & tgt).sum()),
        "frames": int(tgt.shape[0]),
        "frames_correct": int((frame_pred == visible).sum()),
        "frames_visible": int(visible.sum()),
    }
    if distractors is not None:
        if distractors.shape != tgt.shape:
            raise ValueError(
                f"distractors {tuple(distractors.shape)} and target {tuple(tgt.shape)} differ"
            )
        counts["fp_distractor"] = int((pred & distractors.bool() & ~tgt).sum())
    return counts


def confusion_metrics(counts: Mapping[str, int]) -> dict[str, float]:
    """Pixel precision, recall, IoU and frame "goal visible" accuracy from summed counts.

    ``on_distractor`` is the share of predicted goal pixels that lie on a distractor (NaN
    without ``fp_distractor`` counts). A ratio with an empty denominator is NaN, not 0 or 1.
    """

    def ratio(num: float, den: float) -> float:
        return float(num) / float(den) if den > 0 else float("nan")

    tp, fp, fn = counts["tp"], counts["fp"], counts["fn"]
    on_distractor = counts.get("fp_distractor")
    return {
        "pixel_precision": ratio(tp, tp + fp),
        "pixel_recall": ratio(tp, tp + fn),
        "pixel_iou": ratio(tp, tp + fp + fn),
        "visible_accuracy": ratio(counts["frames_correct"], counts["frames"]),
        "visible_rate": ratio(counts["frames_visible"], counts["frames"]),
        "on_distractor": ratio(on_distractor, tp + fp) if on_distractor is not None else math.nan,
    }
