"""Window dataset: exact windows with edge padding, episode split, normalisation."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from vla_gr.data.dataset import EpisodeWindowDataset, split_episodes, window_indices
from vla_gr.data.store import EpisodeStore, fake_episode

LENGTHS = (5, 1, 9, 4)


@pytest.fixture
def store_path(tmp_path):
    path = tmp_path / "s.zarr"
    store = EpisodeStore.create(path, image_size=8)
    for i, n in enumerate(LENGTHS):
        store.append(fake_episode(i, n))
    return path


def test_window_indices_hand_computed():
    obs, obs_pad, act, act_pad = window_indices(1, 4, n_obs_steps=3, horizon=5)
    np.testing.assert_array_equal(obs, [0, 0, 1])
    np.testing.assert_array_equal(obs_pad, [True, False, False])
    np.testing.assert_array_equal(act, [1, 2, 3, 3, 3])
    np.testing.assert_array_equal(act_pad, [False, False, False, True, True])
    with pytest.raises(ValueError, match="t="):
        window_indices(4, 4, 1, 1)


@pytest.mark.parametrize("in_memory", [True, False])
def test_windows_match_store_exactly(store_path, in_memory):
    n_obs, horizon = 3, 4
    ds = EpisodeWindowDataset(
        store_path, n_obs, horizon, split="all", in_memory=in_memory, cache_episodes=1
    )
    assert len(ds) == sum(LENGTHS)
    recs = [fake_episode(i, n) for i, n in enumerate(LENGTHS)]
    i = 0
    for e, rec in enumerate(recs):
        L = len(rec)
        for t in range(L):
            item = ds[i]
            i += 1
            assert item["episode"] == e and item["step"] == t
            obs_idx = [min(max(k, 0), L - 1) for k in range(t - n_obs + 1, t + 1)]
            act_idx = [min(k, L - 1) for k in range(t, t + horizon)]
            np.testing.assert_array_equal(item["pose"].numpy(), rec.pose[obs_idx])
            np.testing.assert_array_equal(item["action"].numpy(), rec.action[act_idx])
            np.testing.assert_array_equal(
                item["depth"].numpy(), rec.depth[obs_idx].transpose(0, 3, 1, 2)
            )
            np.testing.assert_array_equal(item["goal_mask"][:, 0].numpy(), rec.goal_mask[obs_idx])
            np.testing.assert_array_equal(
                item["distractor_mask"][:, 0].numpy(), rec.distractor_mask[obs_idx]
            )
            expected_rgb = rec.rgb[obs_idx].transpose(0, 3, 1, 2) / 255.0
            np.testing.assert_allclose(item["rgb"].numpy(), expected_rgb, rtol=1e-6)
            assert item["rgb"].shape == (n_obs, 3, 8, 8) and item["rgb"].dtype == torch.float32
            assert item["action_is_pad"].tolist() == [k > L - 1 for k in range(t, t + horizon)]
            assert item["obs_is_pad"].tolist() == [k < 0 for k in range(t - n_obs + 1, t + 1)]
            assert item["instruction"] == rec.instruction


def test_in_memory_masks_are_bit_packed_losslessly_at_any_width(tmp_path):
    # Width 10 is not a multiple of 8: unpacking must cut the padding bits off.
    path = tmp_path / "w10.zarr"
    store = EpisodeStore.create(path, image_size=10)
    for i, n in enumerate(LENGTHS):
        store.append(fake_episode(i, n, image_size=10))
    packed = EpisodeWindowDataset(path, 2, 3, split="all", in_memory=True)
    on_disk = EpisodeWindowDataset(path, 2, 3, split="all", in_memory=False)
    assert packed._frames["goal_mask"].shape[1:] == (10, 2)  # 10 columns in 2 bytes
    for i in range(len(packed)):
        a, b = packed[i], on_disk[i]
        for key in ("goal_mask", "distractor_mask"):
            assert a[key].dtype == torch.bool and a[key].shape == b[key].shape == (2, 1, 10, 10)
            assert torch.equal(a[key], b[key])


def test_depth_float16_halves_depth_memory_within_its_rounding(store_path):
    full = EpisodeWindowDataset(store_path, 2, 3, split="all")
    half = EpisodeWindowDataset(store_path, 2, 3, split="all", depth_float16=True)
    saved = full.memory_bytes() - half.memory_bytes()
    assert saved == full._frames["depth"].nbytes // 2 > 0
    worst = 0.0
    for i in range(len(full)):
        a, b = full[i]["depth"], half[i]["depth"]  # (T, 1, H, W)
        assert b.dtype == torch.float32
        worst = max(worst, float(((b - a).abs() / a).max()))
        for key in ("rgb", "pose", "action", "goal_mask"):
            assert torch.equal(full[i][key], half[i][key])
    assert 0.0 < worst <= 2.0**-11


def test_edges_repeat_first_and_last_frame(store_path):
    ds = EpisodeWindowDataset(store_path, n_obs_steps=4, horizon=6, split="all", rgb_uint8=True)
    first = ds[0]  # episode 0, t=0: whole history is frame 0
    assert first["pose"][:, 0].tolist() == [0, 0, 0, 0]
    assert first["rgb"].dtype == torch.uint8 and first["rgb"][:, 0, 0, 0].tolist() == [0] * 4
    last = ds[LENGTHS[0] - 1]  # episode 0, t=4: chunk is 4 then the last frame repeated
    assert (last["action"][:, 0] * 256).tolist() == [4, 4, 4, 4, 4, 4]
    assert last["action_is_pad"].tolist() == [False] + [True] * 5
    one = ds[LENGTHS[0]]  # the one-step episode
    assert one["obs_is_pad"].tolist() == [True, True, True, False]
    assert one["pose"][:, 1].tolist() == [1, 1, 1, 1]  # pose[:, 1] = episode index


def test_split_is_disjoint_deterministic_and_covering():
    tr, va = split_episodes(50, 0.2, seed=3)
    assert len(va) == 10 and len(tr) == 40
    assert set(tr).isdisjoint(va) and set(tr) | set(va) == set(range(50))
    tr2, va2 = split_episodes(50, 0.2, seed=3)
    np.testing.assert_array_equal(va, va2)
    _, va3 = split_episodes(50, 0.2, seed=4)
    assert set(va3) != set(va)
    assert len(split_episodes(3, 0.01)[1]) == 1  # at least one val episode
    assert len(split_episodes(2, 0.9)[0]) == 1  # never all
    with pytest.raises(ValueError, match="val_ratio"):
        split_episodes(5, 1.0)


def test_dataset_split_by_episode(store_path):
    tr = EpisodeWindowDataset(store_path, split="train", val_ratio=0.25, seed=1)
    va = EpisodeWindowDataset(store_path, split="val", val_ratio=0.25, seed=1)
    assert set(tr.episode_ids).isdisjoint(va.episode_ids)
    assert len(tr) + len(va) == sum(LENGTHS)
    eps_in_val = {va[i]["episode"] for i in range(len(va))}
    assert eps_in_val == set(va.episode_ids.tolist())
    sub = EpisodeWindowDataset(store_path, episodes=[2], split="all")
    assert len(sub) == LENGTHS[2]
    with pytest.raises(ValueError, match="out of range"):
        EpisodeWindowDataset(store_path, episodes=[7])


def test_normalized_items_and_loader(store_path):
    ds = EpisodeWindowDataset(store_path, 2, 4, split="all", normalize=True)
    raw = EpisodeWindowDataset(store_path, 2, 4, split="all")
    norm = ds.get_normalizers()["action"]
    batch = next(iter(DataLoader(ds, batch_size=6, shuffle=False)))
    assert batch["action"].shape == (6, 4, 3) and batch["rgb"].shape == (6, 2, 3, 8, 8)
    assert len(batch["instruction"]) == 6
    assert batch["action"].abs().max() <= 1.0 + 1e-6
    torch.testing.assert_close(norm.unnormalize(ds[3]["action"]), raw[3]["action"])


def test_bad_arguments(store_path):
    with pytest.raises(ValueError, match="n_obs_steps"):
        EpisodeWindowDataset(store_path, n_obs_steps=0)
    with pytest.raises(ValueError, match="split"):
        EpisodeWindowDataset(store_path, split="test")


def test_training_depth_float16_reaches_both_datasets(tmp_path):
    from vla_gr.configs import load_config
    from vla_gr.training.data import build_datasets

    path = tmp_path / "train.zarr"
    overrides = [f"training.dataset={path}", "training.batch_size=2"]
    _, cfg = load_config("config_debug", [*overrides, "training.depth_float16=true"])
    store = EpisodeStore.create(path, image_size=cfg.model.image_size)
    for e in range(4):
        store.append(fake_episode(e, 6, image_size=cfg.model.image_size))
    train, val = build_datasets(cfg, path)
    assert train._frames["depth"].dtype == val._frames["depth"].dtype == np.float16
    _, cfg = load_config("config_debug", overrides)
    train, _ = build_datasets(cfg, path)
    assert train._frames["depth"].dtype == np.float32
