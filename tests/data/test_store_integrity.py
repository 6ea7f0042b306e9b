"""Episode store integrity: missing, flipped, truncated chunks and invalid values are caught."""

import json
import logging

import numpy as np
import pytest
import zarr

from vla_gr.data import store as store_module
from vla_gr.data.dataset import EpisodeWindowDataset
from vla_gr.data.store import EpisodeRecord, EpisodeStore, StoreError, fake_episode

LENGTHS = (5, 7, 3)  # frames 0-4, 5-11, 12-14


def _filled(path, lengths=LENGTHS):
    """A store whose rgb/depth/goal_mask hold 4 frames per chunk (8x8 images)."""
    store = EpisodeStore.create(path, image_size=8, chunk_bytes=1024)
    for i, n in enumerate(lengths):
        store.append(fake_episode(i, n))
    assert store.data_array("rgb").chunks[0] == 4
    return path


def _chunk(path, array, index=0):
    arr = zarr.open_array(str(path / array), mode="r")
    tail = (0,) * (arr.ndim - 1)
    return path / array / arr.metadata.encode_chunk_key((index, *tail))


def _flip(file, offset=None):
    raw = bytearray(file.read_bytes())
    i = len(raw) // 2 if offset is None else offset
    raw[i : i + 4] = bytes(b ^ 0xFF for b in raw[i : i + 4])
    file.write_bytes(bytes(raw))


def test_clean_store_opens_without_damage(tmp_path):
    path = _filled(tmp_path / "s.zarr")
    for deep in (False, True):
        store = EpisodeStore.open(path, deep=deep)
        assert store.damage == [] and store.damaged_episodes == []


def test_deleted_chunk_is_refused_naming_store_array_and_episodes(tmp_path):
    path = _filled(tmp_path / "s.zarr")
    _chunk(path, "data/depth", 1).unlink()  # frames 4-7: episodes 0 and 1
    with pytest.raises(StoreError) as err:
        EpisodeStore.open(path)
    msg = str(err.value)
    assert str(path) in msg and "data/depth chunk 1" in msg and "missing" in msg
    assert "episode(s) [0, 1]" in msg and "store verify" in msg


@pytest.mark.parametrize(
    "array",
    [
        "data/rgb",
        "data/depth",
        "data/pose",
        "data/action",
        "data/goal_mask",
        "meta/instruction",
        "meta/spec",
        "meta/metrics",
    ],
)
def test_flipped_bytes_are_refused_in_every_array(tmp_path, array):
    path = _filled(tmp_path / "s.zarr")
    _flip(_chunk(path, array, 0))
    with pytest.raises(StoreError, match=f"{array} chunk 0 .*checksum mismatch") as err:
        EpisodeStore.open(path)
    assert "episode(s) [0" in str(err.value)


def test_flipped_episode_ends_cannot_be_skipped(tmp_path):
    path = _filled(tmp_path / "s.zarr")
    _flip(_chunk(path, "meta/episode_ends", 0))
    with pytest.raises(StoreError, match="meta/episode_ends chunk 0 .*no episode can be located"):
        EpisodeStore.open(path, on_corrupt="skip")


def test_truncated_chunk_is_named(tmp_path):
    path = _filled(tmp_path / "s.zarr")
    file = _chunk(path, "data/rgb", 2)  # frames 8-11: episode 1
    file.write_bytes(file.read_bytes()[:-10])
    with pytest.raises(StoreError, match=r"data/rgb chunk 2 .*truncated .*episodes 1\b"):
        EpisodeStore.open(path)


def test_out_of_range_action_is_damage(tmp_path):
    path = _filled(tmp_path / "s.zarr")
    zarr.open_array(str(path / "data/action"), mode="r+")[13] = [1.0156, 0.0, -1.0]  # valid CRC
    with pytest.raises(StoreError, match=r"data/action chunk 0 .*out of range \[-1.0, 1.0\]"):
        EpisodeStore.open(path)


def test_deep_open_checks_depth_values(tmp_path):
    path = _filled(tmp_path / "s.zarr")
    zarr.open_array(str(path / "data/depth"), mode="r+")[12] = np.nan  # episode 2 only
    assert EpisodeStore.open(path).damage == []  # depth is decoded only when deep
    with pytest.raises(StoreError, match=r"data/depth chunk 3 .*non-finite.*episodes 2\b"):
        EpisodeStore.open(path, deep=True)


def test_record_refuses_invalid_values():
    rec = fake_episode(0, 4)
    action = rec.action.copy()
    action[1, 0] = 1.5
    with pytest.raises(ValueError, match="action has values out of range"):
        EpisodeRecord(0, rec.rgb, rec.depth, rec.pose, action, rec.goal_mask, "x")


def test_all_fill_chunks_are_written(tmp_path):
    """A chunk of all-False goal masks is stored, so a missing one is always damage."""
    store = EpisodeStore.create(tmp_path / "s.zarr", image_size=8, chunk_bytes=1024)
    rec = fake_episode(0, 8)
    rec.goal_mask[:] = False
    store.append(rec)
    assert _chunk(tmp_path / "s.zarr", "data/goal_mask", 0).is_file()
    assert EpisodeStore.open(tmp_path / "s.zarr").damage == []


def test_skip_mode_hides_damaged_episodes(tmp_path, caplog):
    path = _filled(tmp_path / "s.zarr")
    _chunk(path, "data/depth", 1).unlink()
    with caplog.at_level(logging.WARNING):
        store = EpisodeStore.open(path, on_corrupt="skip")
    assert store.damaged_episodes == [0, 1]
    assert "episode(s) [0, 1]" in caplog.text and "skipping" in caplog.text
    with pytest.raises(StoreError, match="episode 1 is damaged"):
        store.episode(1)
    np.testing.assert_array_equal(store.episode(2)["depth"], fake_episode(2, 3).depth)
    ds = EpisodeWindowDataset(store, n_obs_steps=1, horizon=2, split="all")
    assert ds.episode_ids.tolist() == [2] and len(ds) == 3
    assert {ds[i]["episode"] for i in range(len(ds))} == {2}
    with pytest.raises(ValueError, match="read-only"):
        EpisodeStore.open(path, mode="a", on_corrupt="skip")


def _legacy(path):
    """A format-1 store: no checksum codec; then episodes appended through the library."""
    EpisodeStore.create(path, image_size=8, chunk_bytes=1024)
    for meta in path.glob("*/*/zarr.json"):
        doc = json.loads(meta.read_text())
        doc["codecs"] = [c for c in doc["codecs"] if c["name"] != "crc32c"]
        meta.write_text(json.dumps(doc))
    root = json.loads((path / "zarr.json").read_text())
    root["attributes"]["format_version"] = 1
    (path / "zarr.json").write_text(json.dumps(root))
    store = EpisodeStore.open(path, mode="a")
    for i, n in enumerate(LENGTHS):
        store.append(fake_episode(i, n))
    return path


def test_legacy_store_opens_with_one_warning_and_still_finds_missing_chunks(tmp_path, caplog):
    path = _legacy(tmp_path / "old.zarr")
    assert not (path / "data/rgb/zarr.json").read_text().count("crc32c")
    store_module._warned_legacy.discard(str(path))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert EpisodeStore.open(path).num_episodes == 3
        EpisodeStore.open(path)
    assert caplog.text.count("without chunk checksums") == 1
    _chunk(path, "data/goal_mask", 0).unlink()  # format 1 skipped all-False chunks: allowed
    assert EpisodeStore.open(path).damage == []
    _chunk(path, "data/depth", 1).unlink()
    with pytest.raises(StoreError, match="data/depth chunk 1 .*missing"):
        EpisodeStore.open(path)


def test_training_data_refuses_or_skips_damaged_episodes(tmp_path):
    from vla_gr.configs import load_config
    from vla_gr.training.data import build_datasets

    path = tmp_path / "train.zarr"
    overrides = [f"training.dataset={path}", "training.batch_size=2"]
    _, cfg = load_config("config_debug", overrides)
    S = cfg.model.image_size
    store = EpisodeStore.create(path, image_size=S, chunk_bytes=S * S * 3)  # 1 rgb frame/chunk
    for e in range(4):
        store.append(fake_episode(e, 6, image_size=S))
    _chunk(path, "data/rgb", 7).unlink()  # frame 7: episode 1
    with pytest.raises(StoreError, match=r"episode\(s\) \[1\]: data/rgb chunk 7 "):
        build_datasets(cfg, path)
    _, cfg = load_config("config_debug", [*overrides, "training.on_corrupt=skip"])
    train, val = build_datasets(cfg, path)
    used = set(train.episode_ids.tolist()) | set(val.episode_ids.tolist())
    assert used == {0, 2, 3}


def test_store_verify_command_reports_health(tmp_path, capsys):
    from vla_gr.cli import main

    path = _filled(tmp_path / "s.zarr")
    assert main(["store", "verify", str(path)]) == 0
    out = capsys.readouterr().out
    assert (
        "3 episodes, 15 frames" in out
        and "CRC32C" in out
        and out.rstrip().endswith("values in range)")
    )
    assert "data/rgb" in out and "meta/spec" in out and "BAD" not in out
    zarr.open_array(str(path / "data/depth"), mode="r+")[12] = -1.0  # only a deep check sees it
    _chunk(path, "data/rgb", 1).unlink()
    assert main(["store", "verify", "--fast", str(path)]) == 1
    fast = capsys.readouterr().out
    assert "DAMAGED: 1 bad chunk(s) in 2 episode(s) [0, 1]" in fast
    assert main(["store", "verify", str(path)]) == 1
    deep = capsys.readouterr().out
    assert "DAMAGED: 2 bad chunk(s) in 3 episode(s) [0, 1, 2]" in deep
    assert "data/depth chunk 3 (rows 12-14): values out of range [0.0, inf]" in deep
    assert "data/rgb chunk 1 (rows 4-7): missing chunk" in deep


def test_store_verify_reports_a_broken_structure(tmp_path, capsys):
    from vla_gr.data import verify_store

    path = _filled(tmp_path / "s.zarr")
    _flip(_chunk(path, "meta/episode_ends", 0))
    healthy, lines = verify_store(path)
    assert not healthy and lines[0].startswith("DAMAGED: store")
    assert "meta/episode_ends chunk 0" in lines[0] and "checksum mismatch" in lines[0]


def test_train_command_on_a_damaged_store_is_one_line(tmp_path, capsys):
    from vla_gr.cli import main

    path = tmp_path / "train.zarr"
    store = EpisodeStore.create(path, image_size=32)  # config_debug's model.image_size
    for e in range(4):
        store.append(fake_episode(e, 6, image_size=32))
    _chunk(path, "data/depth", 0).unlink()  # one chunk holds every frame
    argv = ["train", "--config-name", "config_debug", f"training.dataset={path}"]
    argv.append(f"training.output_dir={tmp_path / 'runs'}")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "data/depth chunk 0" in err[0] and "on_corrupt=skip" in err[0]
    assert main([*argv, "training.on_corrupt=skip"]) == 2  # nothing intact is left
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "0 training windows" in err[0]


def test_store_copy_adds_checksums_and_salvages_intact_episodes(tmp_path, capsys):
    from vla_gr.cli import main

    old = _legacy(tmp_path / "old.zarr")
    new = tmp_path / "new.zarr"
    assert main(["store", "copy", str(old), str(new)]) == 0
    assert "3 episodes, 15 frames" in capsys.readouterr().out
    assert "crc32c" in (new / "data/rgb/zarr.json").read_text()
    copied, original = EpisodeStore.open(new), EpisodeStore.open(old)
    assert json.loads((new / "zarr.json").read_text())["attributes"]["format_version"] == 2
    for e in range(3):
        for key, values in original.episode(e).items():
            np.testing.assert_array_equal(copied.episode(e)[key], values)
        assert copied.spec(e) == original.spec(e)
    assert copied.stats == original.stats
    damaged = _filled(tmp_path / "damaged.zarr")
    _chunk(damaged, "data/depth", 1).unlink()  # episodes 0 and 1
    salvaged = tmp_path / "salvaged.zarr"
    assert main(["store", "copy", str(damaged), str(salvaged)]) == 2  # refused by default
    assert "data/depth chunk 1" in capsys.readouterr().err and not salvaged.exists()
    assert main(["store", "copy", "--skip-damaged", str(damaged), str(salvaged)]) == 0
    kept = EpisodeStore.open(salvaged)
    assert kept.episode_indices.tolist() == [2] and kept.damage == []
