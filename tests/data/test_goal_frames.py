"""Goal frames: every stride-th frame, the goal mask as target, balanced sampling weights."""

import numpy as np
import pytest
import torch

from vla_gr.data.goal_frames import GoalFrameDataset
from vla_gr.data.store import EpisodeStore, fake_episode

LENGTHS = (5, 7)


@pytest.fixture
def store(tmp_path):
    store = EpisodeStore.create(tmp_path / "s.zarr", image_size=8)
    for i, n in enumerate(LENGTHS):
        rec = fake_episode(i, n)
        rec.goal_mask[:] = False
        rec.goal_mask[n - 2 :, :3, :3] = True  # the goal shows in the last two frames (9 px)
        store.append(rec)
    return EpisodeStore.open(tmp_path / "s.zarr")


def test_items_are_the_stored_frames(store):
    ds = GoalFrameDataset(store, frame_stride=2)
    assert len(ds) == sum(len(range(0, n, 2)) for n in LENGTHS)  # 3 + 4
    item = ds[4]  # episode 1, step 2
    assert (item["episode"], item["step"]) == (1, 2)
    assert item["rgb"].shape == (3, 8, 8) and item["rgb"].dtype == torch.uint8
    assert int(item["rgb"][0, 0, 0]) == 2  # fake frames carry their step as the pixel value
    assert item["depth"].shape == (1, 8, 8) and item["goal_mask"].shape == (8, 8)
    assert item["instruction"] == store.instruction(1)
    raw = store.episode(1)["depth"][2, ..., 0]
    np.testing.assert_array_equal(item["depth"][0].numpy(), raw)
    distractors = store.episode(1)["distractor_mask"][2]
    assert distractors.any()
    np.testing.assert_array_equal(item["distractor_mask"].numpy(), distractors)


def test_visibility_and_balanced_weights(store):
    ds = GoalFrameDataset(store, min_pixels=9)
    expected = np.concatenate([np.arange(n) >= n - 2 for n in LENGTHS])
    np.testing.assert_array_equal(ds.visible, expected)
    w = ds.sample_weights()
    assert w[torch.from_numpy(ds.visible)].sum().item() == pytest.approx(0.5)
    assert w.sum().item() == pytest.approx(1.0)
    assert GoalFrameDataset(store, min_pixels=10).visible.sum() == 0


def test_flip_mirrors_image_and_mask_together(store):
    ds = GoalFrameDataset(store, episodes=[1], flip=True, seed=3)
    flipped = [ds[6] for _ in range(20)]
    masks = {tuple(item["goal_mask"][0].tolist()) for item in flipped}
    assert len(masks) == 2  # both orientations occur
    for item in flipped:
        left = bool(item["goal_mask"][0, 0])
        raw = store.episode(1)["depth"][6, 0, :, 0]
        row = item["depth"][0, 0].numpy()
        np.testing.assert_array_equal(row, raw if left else raw[::-1])
        others = store.episode(1)["distractor_mask"][6]  # (H, W)
        np.testing.assert_array_equal(
            item["distractor_mask"].numpy(), others if left else others[:, ::-1]
        )


def test_bad_arguments(store):
    with pytest.raises(ValueError, match="frame_stride"):
        GoalFrameDataset(store, frame_stride=0)
    with pytest.raises(ValueError, match="no episodes"):
        GoalFrameDataset(store, episodes=[])
