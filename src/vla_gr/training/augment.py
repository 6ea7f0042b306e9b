"""Training-time augmentation of goal-head batches: paraphrased instructions, mirrored frames.

Both draw from torch's global RNG, which a checkpoint saves and ``training.resume`` restores,
so a resumed run replays the same augmentations. Each is a no-op at probability 0 (and then
draws nothing, so runs without it keep their RNG stream).
"""

from __future__ import annotations

import torch

from vla_gr.envs.paraphrase import paraphrase_instructions

__all__ = ["IMAGE_KEYS", "augment_batch", "mirror_frames"]

#: batch entries laid out as images (B, T, C, H, W): mirrored together, so masks stay aligned
IMAGE_KEYS = ("rgb", "depth", "goal_mask", "distractor_mask")


def mirror_frames(batch: dict, prob: float) -> dict:
    """``batch`` with each window's images mirrored left-right with probability ``prob``.

    Only the image entries (:data:`IMAGE_KEYS`, each (B, T, C, H, W)) change: a mirrored
    window's RGB, depth and masks are all flipped along W. The instructions never say left or
    right, so the goal mask of a mirrored frame is the mirrored goal mask. Poses and actions
    are left alone, which is why only the goal head may train on mirrored frames.
    """
    if prob <= 0.0:
        return batch
    present = [k for k in IMAGE_KEYS if k in batch]
    if not present:
        return batch
    B = batch[present[0]].shape[0]
    chosen = torch.rand(B) < prob  # (B,) windows to mirror
    out = dict(batch)
    for key in present:
        x = batch[key]  # (B, T, C, H, W)
        if x.dim() != 5 or x.shape[0] != B:
            raise ValueError(f"batch[{key!r}] must be (B={B}, T, C, H, W); got {tuple(x.shape)}")
        where = chosen.to(x.device)[:, None, None, None, None]  # (B, 1, 1, 1, 1)
        out[key] = torch.where(where, x.flip(-1), x)  # (B, T, C, H, W)
    return out


def augment_batch(batch: dict, paraphrase_prob: float = 0.0, flip_prob: float = 0.0) -> dict:
    """``batch`` with its instructions rewritten in the training paraphrase vocabulary with
    ``paraphrase_prob`` each, then its frames mirrored with ``flip_prob`` each."""
    if paraphrase_prob > 0.0:
        instructions = paraphrase_instructions(list(batch["instruction"]), paraphrase_prob)
        batch = {**batch, "instruction": instructions}
    return mirror_frames(batch, flip_prob)
