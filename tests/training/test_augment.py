"""Goal-head batch augmentation: mirrored frames keep their masks aligned, under a seed."""

from __future__ import annotations

import pytest
import torch

from vla_gr.training.augment import augment_batch, mirror_frames


def _batch(B: int = 6, T: int = 2, H: int = 4, W: int = 5) -> dict:
    g = torch.Generator().manual_seed(0)
    rgb = torch.randint(0, 256, (B, T, 3, H, W), generator=g, dtype=torch.uint8)
    goal = torch.zeros(B, T, 1, H, W, dtype=torch.bool)
    goal[..., 0] = True  # the goal fills the left column of every frame
    return {
        "rgb": rgb,
        "depth": torch.rand(B, T, 1, H, W, generator=g),
        "goal_mask": goal,
        "distractor_mask": ~goal,
        "action": torch.randn(B, 4, 3, generator=g),
        "instruction": [f"find the chair {i}" for i in range(B)],
    }


def test_mirrored_windows_are_exact_flips_and_the_rest_unchanged():
    batch = _batch(B=64)
    torch.manual_seed(3)
    out = mirror_frames(batch, 0.5)
    flipped = out["goal_mask"][:, 0, 0, 0, -1]  # (B,) the goal moved to the right column
    assert 0 < int(flipped.sum()) < 64  # some windows, not all
    for key in ("rgb", "depth", "goal_mask", "distractor_mask"):
        want = torch.where(flipped[:, None, None, None, None], batch[key].flip(-1), batch[key])
        assert torch.equal(out[key], want), key
    assert torch.equal(out["action"], batch["action"])  # actions are never mirrored
    assert out["instruction"] == batch["instruction"]


def test_probability_one_mirrors_all_and_zero_draws_nothing():
    batch = _batch()
    assert torch.equal(mirror_frames(batch, 1.0)["rgb"], batch["rgb"].flip(-1))
    torch.manual_seed(5)
    state = torch.get_rng_state()
    assert mirror_frames(batch, 0.0) is batch
    assert augment_batch(batch) is batch
    assert torch.equal(torch.get_rng_state(), state)  # runs without it keep their RNG stream


def test_same_seed_same_mirrors():
    batch = _batch(B=32)
    torch.manual_seed(11)
    a = mirror_frames(batch, 0.5)["goal_mask"]
    torch.manual_seed(11)
    b = mirror_frames(batch, 0.5)["goal_mask"]
    assert torch.equal(a, b)


def test_image_entries_of_the_wrong_shape_are_refused():
    batch = _batch()
    batch["depth"] = batch["depth"][:, 0]  # (B, 1, H, W): no time axis
    with pytest.raises(ValueError, match="depth"):
        mirror_frames(batch, 1.0)
