"""Train S2's object-category segmenter (:mod:`vla_gr.agent.perception.object_category`).

Labels of a frame: the category of the object every pixel shows, from the world's geometry
(:mod:`vla_gr.training.object_labels`: the stored depth and pose, back-projected into the
house regenerated from the episode's spec). Whole houses are held out for validation, and the
weights with the best held-out mean IoU over the categories are kept. The rest of the agent
comes from ``init`` and stays fixed. The result is the agent with
``model.object_category.enabled=true`` and the object check on
(``navigator.goal_checks.object_reject_threshold``), a checkpoint that ``vla-gr eval`` loads
like any other.

A recipe's ``object_category`` stage runs it (``training.object_category.*``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.training.agent_stage import (
    labelled_frames,
    part_setting,
    train_frame_part,
)
from vla_gr.training.object_labels import frame_categories
from vla_gr.training.part_training import ON_CPU, Compute

log = logging.getLogger(__name__)

__all__ = ["category_frames", "segmentation_scores", "train_object_category"]


def category_frames(
    store_path: str | Path,
    categories: Sequence[str],
    first: int = 0,
    count: int | None = None,
    stride: int = 1,
) -> dict[str, np.ndarray]:
    """Every ``stride``-th frame of stored episodes ``[first, first + count)`` with its
    per-pixel labels: ``rgb`` (N, 3, H, W) uint8, ``depth`` (N, 1, H, W) float32, ``label``
    (N, H, W) uint8 (0 background, k = ``categories[k - 1]``) and ``house`` (N,)."""
    houses: dict = {}
    return labelled_frames(
        store_path,
        lambda spec, f: frame_categories(spec, f["pose"], f["depth"], categories, houses),
        first,
        count,
        stride,
    )


@torch.no_grad()
def segmentation_scores(segmenter, frames: dict[str, np.ndarray], batch_size: int = 256) -> dict:
    """Per-pixel scores of ``segmenter`` on ``frames`` (:func:`category_frames`): accuracy,
    IoU per category and their mean, and how often the argmax inside each category's true
    pixels is that category (what the object check reads)."""
    segmenter.eval()
    K = 1 + len(segmenter.config.categories)
    confusion = np.zeros((K, K), np.int64)  # (true, predicted)
    device = next(segmenter.parameters()).device
    for i in range(0, len(frames["label"]), batch_size):
        rgb = torch.from_numpy(frames["rgb"][i : i + batch_size]).to(device)  # (b, 3, H, W)
        depth = torch.from_numpy(frames["depth"][i : i + batch_size]).to(device)  # (b, 1, H, W)
        predicted = segmenter(rgb, depth).argmax(1).cpu().numpy().reshape(-1)  # (b * H * W,)
        true = frames["label"][i : i + batch_size].reshape(-1).astype(np.int64)  # (b * H * W,)
        confusion += np.bincount(true * K + predicted, minlength=K * K).reshape(K, K)
    hits = np.diag(confusion)  # (K,)
    union = confusion.sum(0) + confusion.sum(1) - hits  # (K,)
    present = confusion.sum(1) > 0  # (K,) classes with true pixels
    iou = np.where(union > 0, hits / np.maximum(union, 1), np.nan)  # (K,)
    names = list(segmenter.config.categories)
    per_category = {n: round(float(iou[k + 1]), 4) for k, n in enumerate(names) if present[k + 1]}
    return {
        "frames": int(len(frames["label"])),
        "pixel_accuracy": round(float(hits.sum() / max(confusion.sum(), 1)), 4),
        "mean_iou": round(float(np.nanmean(iou[1:][present[1:]])), 4) if present[1:].any() else 0.0,
        "iou": per_category,
        "recall": {
            n: round(float(hits[k + 1] / confusion[k + 1].sum()), 4)
            for k, n in enumerate(names)
            if present[k + 1]
        },
    }


def train_object_category(
    init: str | Path,
    out: str | Path,
    frames: dict[str, np.ndarray],
    categories: Sequence[str],
    steps: int = 3000,
    batch_size: int = 64,
    lr: float = 2e-3,
    seed: int = 0,
    settings: Sequence[str] = (),
    reject_threshold: float = 0.3,
    background_weight: float = 0.5,
    val_fraction: float = 0.1,
    eval_every: int = 250,
    eval_frames: dict[str, np.ndarray] | None = None,
    compute: Compute = ON_CPU,
) -> dict:
    """Train the segmenter on ``frames`` (labelled in ``categories``' order; background
    pixels weigh ``background_weight``) and write the agent to ``out``; returns the summary."""
    weight = torch.ones(1 + len(categories))  # (1 + K,)
    weight[0] = background_weight
    return train_frame_part(
        init, out, frames, categories, settings, reject_threshold, eval_frames,
        part="object_category", labels_key="categories", role="segmenter",
        threshold_key="object_reject_threshold",
        batch_loss=lambda segmenter, rgb, depth, label: F.cross_entropy(
            segmenter(rgb, depth), label.long(), weight=weight.to(rgb.device)
        ),
        evaluate=segmentation_scores, score="mean_iou", name="object category", seed=seed,
        steps=steps, batch_size=batch_size, lr=lr, val_fraction=val_fraction,
        eval_every=eval_every, compute=compute,
    )  # fmt: skip


def labels(settings: Sequence[str]) -> list[str]:
    """``object_category.categories`` after ``settings`` (the classes frames are labelled in)."""
    from vla_gr.agent.perception import ObjectCategoryConfig

    return part_setting(ObjectCategoryConfig, "object_category", "categories", settings)
