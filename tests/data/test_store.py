"""Episode store: layout, validation, commit protocol, crash repair, statistics."""

import json

import numpy as np
import pytest
import zarr

from vla_gr.data.normalize import MinMaxNormalizer, compute_stats, merge_stats
from vla_gr.data.store import EpisodeRecord, EpisodeStore, StoreError, fake_episode


def _filled(path, lengths=(5, 7, 3), start=0):
    store = EpisodeStore.create(path, image_size=8)
    for i, n in enumerate(lengths):
        assert store.append(fake_episode(start + i, n))
    return store


def test_round_trip_and_layout(tmp_path):
    path = tmp_path / "s.zarr"
    _filled(path)
    store = EpisodeStore.open(path)
    assert store.num_episodes == 3 and store.num_frames == 15
    np.testing.assert_array_equal(store.episode_ends, [5, 12, 15])
    assert store.episode_ends.dtype == np.int64
    rec = fake_episode(1, 7)
    ep = store.episode(1)
    for key, values in rec.frames().items():
        np.testing.assert_array_equal(ep[key], values)
        assert ep[key].dtype == values.dtype
    assert store.instruction(1) == rec.instruction
    assert store.spec(1) == rec.spec and store.metrics(2) == {"success": 1.0, "spl": 1.0}
    g = zarr.open_group(str(path), mode="r")
    assert g["data/rgb"].shape == (15, 8, 8, 3) and g["data/goal_mask"].dtype == bool
    assert g["data/rgb"].compressors  # compressed
    assert g.attrs["format_version"] == 2


def test_record_validates_shapes():
    rec = fake_episode(0, 4)
    with pytest.raises(ValueError, match="depth"):
        EpisodeRecord(0, rec.rgb, rec.depth[:3], rec.pose, rec.action, rec.goal_mask, "x")


def test_missing_array_is_named(tmp_path):
    path = tmp_path / "s.zarr"
    _filled(path)
    g = zarr.open_group(str(path), mode="r+")
    del g["data/depth"]
    with pytest.raises(StoreError, match="missing array 'data/depth'"):
        EpisodeStore.open(path)


def test_mismatched_lengths_are_named(tmp_path):
    path = tmp_path / "s.zarr"
    _filled(path)
    g = zarr.open_group(str(path), mode="r+")
    g["data/pose"].resize((10, 3))
    with pytest.raises(StoreError, match=r"data/pose has 10 frames .* needs 15"):
        EpisodeStore.open(path)
    g["data/pose"].resize((15, 3))
    g["meta/instruction"].resize((2,))
    with pytest.raises(StoreError, match=r"meta/instruction has 2 entries .* 3 episodes"):
        EpisodeStore.open(path)


def test_not_a_store(tmp_path):
    with pytest.raises(StoreError, match="not an episode store"):
        EpisodeStore.open(tmp_path)


def test_create_refuses_existing(tmp_path):
    path = tmp_path / "s.zarr"
    _filled(path)
    with pytest.raises(FileExistsError):
        EpisodeStore.create(path, 8)
    store = EpisodeStore.create(path, 8, overwrite=True)
    assert store.num_episodes == 0


def test_append_skips_duplicates_and_reopen(tmp_path):
    path = tmp_path / "s.zarr"
    _filled(path, lengths=(4, 4))
    store = EpisodeStore.open(path, mode="a")
    assert not store.append(fake_episode(1, 9))  # index 1 already there
    assert store.append(fake_episode(5, 6))
    store = EpisodeStore.open(path)
    np.testing.assert_array_equal(store.episode_indices, [0, 1, 5])
    np.testing.assert_array_equal(store.episode_ends, [4, 8, 14])
    with pytest.raises(StoreError, match="read-only"):
        store.append(fake_episode(7, 2))


def _simulate_crash(path, record):
    """Write frames and some meta of ``record`` but not the commit (as a killed run would)."""
    g = zarr.open_group(str(path), mode="r+")
    for key, values in record.frames().items():
        if key != "goal_mask":  # killed mid-way: goal_mask never written
            g[f"data/{key}"].append(values)
    g["meta/episode_index"].append(np.array([record.episode_index]))
    g["meta/instruction"].append(np.array([record.instruction], dtype=str))


def test_crash_residue_is_ignored_then_repaired(tmp_path):
    path = tmp_path / "s.zarr"
    _filled(path, lengths=(5, 6))
    stats_before = EpisodeStore.open(path).stats
    _simulate_crash(path, fake_episode(2, 9))
    store = EpisodeStore.open(path)  # readable: residue ignored
    assert store.has_uncommitted()
    assert store.num_episodes == 2 and store.num_frames == 11
    assert store.data_array("rgb").shape[0] == 20
    assert store.stats == stats_before
    # Opening for append truncates; re-appending the same index then succeeds.
    store = EpisodeStore.open(path, mode="a")
    assert not store.has_uncommitted()
    assert store.data_array("rgb").shape[0] == 11
    rec = fake_episode(2, 4)
    assert store.append(rec)
    store = EpisodeStore.open(path)
    np.testing.assert_array_equal(store.episode_ends, [5, 11, 15])
    np.testing.assert_array_equal(store.episode(2)["goal_mask"], rec.goal_mask)
    np.testing.assert_array_equal(store.episode(2)["rgb"], rec.rgb)
    assert store.instruction(2) == rec.instruction


def test_stats_updated_on_append_equal_full_recompute(tmp_path):
    path = tmp_path / "s.zarr"
    recs = [fake_episode(i, n) for i, n in enumerate((5, 8, 2))]
    store = EpisodeStore.create(path, 8)
    for r in recs:
        store.append(r)
    stats = EpisodeStore.open(path).stats
    actions = np.concatenate([r.action for r in recs])
    full = compute_stats(actions)
    np.testing.assert_allclose(stats["action"]["mean"], actions.mean(0), rtol=1e-6)
    np.testing.assert_allclose(stats["action"]["std"], actions.std(0), rtol=1e-5)
    np.testing.assert_allclose(stats["action"]["min"], full["min"])
    np.testing.assert_allclose(stats["action"]["max"], full["max"])
    depth = np.concatenate([r.depth for r in recs]).ravel()
    assert stats["depth"]["min"][0] == pytest.approx(depth.min())
    assert stats["depth"]["max"][0] == pytest.approx(depth.max())
    assert stats["pose"]["max"][1] == 2.0  # pose[:, 1] = episode index
    json.dumps(stats)  # JSON-able


def test_merge_stats_with_empty_dimension():
    a = compute_stats(np.array([[1.0, np.nan], [3.0, np.nan]]))
    assert a["min"][1] is None and a["max"][1] is None
    b = compute_stats(np.array([[-2.0, 4.0]]))
    m = merge_stats(a, b)
    assert m["min"] == [-2.0, 4.0] and m["max"] == [3.0, 4.0]
    assert m["count"] == [3.0, 1.0]
    assert merge_stats(None, b) == b


def test_normalizer_round_trip_and_bounds():
    rng = np.random.default_rng(0)
    x = rng.uniform([-3, 0, 5], [2, 10, 5], size=(100, 3))  # last dim constant
    norm = MinMaxNormalizer.from_stats(compute_stats(x))
    y = norm.normalize(x)
    assert y[:, :2].min() == pytest.approx(-1.0) and y[:, :2].max() == pytest.approx(1.0)
    np.testing.assert_allclose(y[:, 2], 0.0)  # constant dim -> 0
    np.testing.assert_allclose(norm.unnormalize(y), x, atol=1e-9)
    # Hand-computed: [-3, 2] -> [-1, 1] maps 0 to 2 * 3 / 5 - 1 = 0.2
    lo, hi = x[:, 0].min(), x[:, 0].max()
    assert norm.normalize(np.array([[0.0, 0.0, 5.0]]))[0, 0] == pytest.approx(
        2 * (0 - lo) / (hi - lo) - 1
    )
    import torch

    t = torch.tensor(x, dtype=torch.float32)
    torch.testing.assert_close(norm.unnormalize(norm.normalize(t)), t, atol=1e-5, rtol=1e-5)
    again = MinMaxNormalizer.from_dict(norm.to_dict())
    np.testing.assert_allclose(again.normalize(x), y)
    with pytest.raises(ValueError, match="last dim"):
        norm.normalize(np.zeros((2, 4)))


class _KilledError(Exception):
    pass


def _killed(*args, **kwargs):
    raise _KilledError


@pytest.mark.parametrize(
    "fail_at", ["data/goal_mask", "meta/metrics", "meta/episode_ends", "commit"]
)
def test_interrupted_append_never_corrupts(tmp_path, monkeypatch, fail_at):
    """Kill the real append at each stage: committed episodes survive, the next append repairs."""
    path = tmp_path / "s.zarr"
    _filled(path, lengths=(5, 6))
    store = EpisodeStore.open(path, mode="a")
    if fail_at == "commit":
        monkeypatch.setattr(store, "_commit", _killed)
    else:
        group, key = fail_at.split("/")
        target = (store._data if group == "data" else store._meta)[key]
        monkeypatch.setattr(target, "append", _killed)
    with pytest.raises(_KilledError):
        store.append(fake_episode(2, 9))
    monkeypatch.undo()
    reopened = EpisodeStore.open(path)
    assert reopened.num_episodes == 2 and reopened.num_frames == 11
    np.testing.assert_array_equal(reopened.episode(1)["pose"], fake_episode(1, 6).pose)
    assert reopened.has_uncommitted()  # frames of episode 2 were written before the failure
    store = EpisodeStore.open(path, mode="a")
    assert store.append(fake_episode(2, 3))
    final = EpisodeStore.open(path)
    assert not final.has_uncommitted()
    np.testing.assert_array_equal(final.episode_indices, [0, 1, 2])
    np.testing.assert_array_equal(final.episode_ends, [5, 11, 14])
    np.testing.assert_array_equal(final.episode(2)["action"], fake_episode(2, 3).action)


def test_creation_is_atomic(tmp_path, monkeypatch):
    """A failure while building a new store leaves no store at the path (never half-created)."""
    path = tmp_path / "new.zarr"

    def boom(*args, **kwargs):
        raise RuntimeError("killed while creating")

    monkeypatch.setattr(zarr.Group, "create_array", boom)
    with pytest.raises(RuntimeError, match="killed while creating"):
        EpisodeStore.create(path, image_size=8)
    assert not path.exists()
    monkeypatch.undo()
    store = EpisodeStore.create(path, image_size=8, overwrite=True)
    assert store.num_episodes == 0
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["new.zarr"]
    assert EpisodeStore.open(path).num_episodes == 0
