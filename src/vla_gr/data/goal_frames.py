"""Single frames for the goal head: (RGB-D, instruction) -> the goal instance's mask.

Reads committed episodes of an :class:`~vla_gr.data.store.EpisodeStore` into memory (every
``frame_stride``-th frame). Targets come from ``goal_mask``: the pixels of the instance the
instruction names, so pixels of same-category distractors are negatives. Frames that show
the goal are rare on the way to it; :meth:`GoalFrameDataset.sample_weights` gives a
``WeightedRandomSampler`` equal odds of drawing a frame with and without the goal.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from vla_gr.data.store import EpisodeStore

log = logging.getLogger(__name__)

__all__ = ["GoalFrameDataset"]


class GoalFrameDataset(Dataset):
    """Frames of the given store rows (all committed episodes when ``episodes`` is None).

    Each item: ``rgb`` (3, H, W) uint8, ``depth`` (1, H, W) float32 metres, ``goal_mask``
    (H, W) bool, ``distractor_mask`` (H, W) bool (when the store holds it), ``instruction``
    str, ``episode`` int (store row), ``step`` int.
    ``flip=True`` mirrors a random half of the items left-right (instructions never say
    left or right, so the label is unchanged).
    """

    def __init__(
        self,
        store: EpisodeStore,
        episodes: Sequence[int] | None = None,
        frame_stride: int = 1,
        min_pixels: int = 4,
        flip: bool = False,
        seed: int = 0,
    ) -> None:
        if frame_stride < 1:
            raise ValueError(f"frame_stride={frame_stride} must be >= 1")
        rows = range(store.num_episodes) if episodes is None else [int(e) for e in episodes]
        if len(rows) == 0:
            raise ValueError(f"no episodes selected from store {store.path}")
        rgb, depth, mask, others, where = [], [], [], [], []
        self.instructions = [store.instruction(e) for e in rows]
        has_distractors = "distractor_mask" in store.frame_keys
        keys = ("rgb", "depth", "goal_mask") + (("distractor_mask",) if has_distractors else ())
        for i, e in enumerate(rows):
            ep = store.episode(e, keys=keys)
            steps = np.arange(0, len(ep["rgb"]), frame_stride)  # (n,)
            rgb.append(ep["rgb"][steps])  # (n, H, W, 3)
            depth.append(ep["depth"][steps])  # (n, H, W, 1)
            mask.append(ep["goal_mask"][steps])  # (n, H, W)
            if has_distractors:
                others.append(ep["distractor_mask"][steps])  # (n, H, W)
            where.append(np.stack([np.full(len(steps), i), steps, np.full(len(steps), e)], 1))
        self.rgb = np.concatenate(rgb)  # (N, H, W, 3)
        self.depth = np.concatenate(depth)  # (N, H, W, 1)
        self.goal_mask = np.concatenate(mask)  # (N, H, W)
        self.distractor_mask = np.concatenate(others) if has_distractors else None  # (N, H, W)
        self.where = np.concatenate(where)  # (N, 3) instruction slot, step, store row
        self.visible = self.goal_mask.reshape(len(self.goal_mask), -1).sum(1) >= min_pixels
        self.flip = flip
        self._rng = np.random.default_rng(seed)
        log.info(
            "goal frames: %d from %d episodes, goal visible in %.1f%%",
            len(self), len(rows), 100.0 * float(self.visible.mean()),
        )  # fmt: skip

    def __len__(self) -> int:
        return int(self.rgb.shape[0])

    def sample_weights(self) -> torch.Tensor:
        """(N,) weights that draw goal-visible and goal-absent frames equally often."""
        n_vis = max(int(self.visible.sum()), 1)
        n_hid = max(int((~self.visible).sum()), 1)
        w = np.where(self.visible, 0.5 / n_vis, 0.5 / n_hid)  # (N,)
        return torch.as_tensor(w, dtype=torch.double)

    def __getitem__(self, i: int) -> dict:
        slot, step, row = (int(v) for v in self.where[i])
        rgb = self.rgb[i].transpose(2, 0, 1)  # (3, H, W)
        depth = self.depth[i].transpose(2, 0, 1)  # (1, H, W)
        masks = {"goal_mask": self.goal_mask[i]}  # (H, W)
        if self.distractor_mask is not None:
            masks["distractor_mask"] = self.distractor_mask[i]  # (H, W)
        if self.flip and self._rng.random() < 0.5:
            rgb, depth = rgb[..., ::-1], depth[..., ::-1]
            masks = {k: m[..., ::-1] for k, m in masks.items()}
        item = {
            "rgb": torch.from_numpy(np.ascontiguousarray(rgb)),
            "depth": torch.from_numpy(np.ascontiguousarray(depth, dtype=np.float32)),
            "instruction": self.instructions[slot],
            "episode": row,
            "step": step,
        }
        return item | {k: torch.from_numpy(np.ascontiguousarray(m)) for k, m in masks.items()}
