"""LeRobotDataset export: the files hold exactly the store's episodes (read back with pyarrow
here); the slow test loads them with lerobot's own ``LeRobotDataset`` in its virtualenv."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image

from vla_gr.cli import main
from vla_gr.data import lerobot_export
from vla_gr.data.lerobot_export import QUANTILES, export_lerobot
from vla_gr.data.store import EpisodeStore, StoreError, fake_episode
from vla_gr.errors import UserError

ROOT = Path(__file__).resolve().parents[2]
LEROBOT_PYTHON = ROOT / ".venv-lerobot" / "bin" / "python"
READER = Path(__file__).with_name("lerobot_read.py")
LENGTHS = (5, 7, 3, 6)
FPS = 10


def _store(path: Path, info: dict | None = None) -> EpisodeStore:
    """Four episodes of noisy 8x8 images; episodes 0 and 2 share their instruction."""
    store = EpisodeStore.create(path, 8, info={"control_hz": float(FPS)} if info is None else info)
    rng = np.random.default_rng(3)
    for i, T in enumerate(LENGTHS):
        record = fake_episode(10 + i, T)
        record = dataclasses.replace(
            record,
            rgb=rng.integers(0, 256, record.rgb.shape, dtype=np.uint8),
            instruction="find the bed" if i in (0, 2) else record.instruction,
            spec={"episode_id": 10 + i, "goal": "bed"},
        )
        assert store.append(record)
    return store


def _read_data(root: Path) -> tuple[pa.Table, list[Path]]:
    files = sorted((root / "data").glob("chunk-*/file-*.parquet"))
    return pa.concat_tables([pq.read_table(f) for f in files]), files


def _inverted_cdf(x: np.ndarray) -> np.ndarray:
    """(Q, C) quantiles of the rows of ``x`` (n, C): the smallest value v with at least a
    fraction q of the values <= v."""
    s = np.sort(x, axis=0)
    ranks = np.ceil(np.array(QUANTILES) * len(s)).astype(int) - 1
    return s[np.clip(ranks, 0, len(s) - 1)]


@pytest.fixture
def exported(tmp_path):
    store = _store(tmp_path / "s.zarr")
    # ~0.003 MB per file: a file closes after one or two episodes, so several are written.
    result = export_lerobot(store.path, tmp_path / "out", data_file_mb=0.003)
    return store, result, tmp_path / "out"


def test_frames_are_the_stores_exactly(exported):
    store, result, root = exported
    N, E = store.num_frames, store.num_episodes
    assert (result.episodes, result.frames, result.tasks, result.fps) == (E, N, 3, FPS)
    table, files = _read_data(root)
    assert result.data_files == len(files) >= 2 and table.num_rows == N
    data = {k: store.data_array(k)[:N] for k in ("rgb", "depth", "pose", "action")}
    images = table["observation.image"].to_pylist()
    decoded = np.stack([np.asarray(Image.open(io.BytesIO(im["bytes"]))) for im in images])
    np.testing.assert_array_equal(decoded, data["rgb"])  # lossless
    depth = np.asarray(table["observation.depth"].to_pylist(), dtype=np.float32)
    np.testing.assert_array_equal(depth, data["depth"])
    for feature, key in (("observation.state", "pose"), ("action", "action")):
        column = np.asarray(table[feature].to_pylist(), dtype=np.float32)
        np.testing.assert_array_equal(column, data[key])
    ends = store.episode_ends
    episode = np.repeat(np.arange(E), LENGTHS)
    frame = np.concatenate([np.arange(T) for T in LENGTHS])
    np.testing.assert_array_equal(table["episode_index"].to_numpy(), episode)
    np.testing.assert_array_equal(table["frame_index"].to_numpy(), frame)
    np.testing.assert_array_equal(table["index"].to_numpy(), np.arange(N))
    np.testing.assert_allclose(table["timestamp"].to_numpy(), frame / FPS, rtol=1e-6)
    assert table["timestamp"].type == pa.float32() and ends[-1] == N
    tasks = pq.read_table(root / "meta" / "tasks.parquet")
    assert tasks["__index_level_0__"].to_pylist() == [store.instruction(e) for e in (0, 1, 3)]
    assert tasks["task_index"].to_pylist() == [0, 1, 2]
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["__index_level_0__"]
    task_of_frame = [tasks["__index_level_0__"][i].as_py() for i in table["task_index"].to_numpy()]
    assert task_of_frame == [store.instruction(e) for e in episode]


def test_metadata_locates_every_episode(exported):
    store, _, root = exported
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == FPS
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (4, 21, 3)
    assert info["splits"] == {"train": "0:4"} and info["video_path"] is None
    assert info["features"]["observation.image"] == {
        "dtype": "image",
        "shape": [8, 8, 3],
        "names": ["height", "width", "channels"],
    }
    assert info["features"]["observation.depth"]["shape"] == [8, 8, 1]
    assert info["features"]["action"]["names"] == ["linear_velocity", "angular_velocity", "stop"]
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [ep["episode_index"] for ep in episodes] == [0, 1, 2, 3]
    for e, ep in enumerate(episodes):
        sl = store.episode_slice(e)
        assert (ep["dataset_from_index"], ep["dataset_to_index"]) == (sl.start, sl.stop)
        assert ep["length"] == LENGTHS[e] and ep["tasks"] == [store.instruction(e)]
        path = root / info["data_path"].format(
            chunk_index=ep["data/chunk_index"], file_index=ep["data/file_index"]
        )
        in_file = pq.read_table(path, columns=["episode_index"])["episode_index"].to_numpy()
        assert (in_file == e).sum() == LENGTHS[e]  # the whole episode is in the named file
        assert ep["vla_gr/episode_index"] == 10 + e
        assert json.loads(ep["vla_gr/spec"]) == store.spec(e)
        assert json.loads(ep["vla_gr/metrics"]) == store.metrics(e)


def test_statistics_follow_lerobots_rules(exported):
    store, _, root = exported
    stats = json.loads((root / "meta" / "stats.json").read_text())
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    N = store.num_frames
    per_pixel = {
        "observation.image": lambda e: store.episode(e)["rgb"].reshape(-1, 3) / 255.0,
        "observation.depth": lambda e: store.episode(e)["depth"].reshape(-1, 1),
        "action": lambda e: store.episode(e)["action"],
    }
    for feature, values_of in per_pixel.items():
        shape = (3, 1, 1) if feature == "observation.image" else (-1,)
        every = np.concatenate([values_of(e) for e in range(store.num_episodes)]).astype(float)
        got = {k: np.asarray(v) for k, v in stats[feature].items()}
        assert got["count"].tolist() == [N]
        np.testing.assert_allclose(got["min"], every.min(0).reshape(shape), rtol=1e-6)
        np.testing.assert_allclose(got["max"], every.max(0).reshape(shape), rtol=1e-6)
        np.testing.assert_allclose(got["mean"], every.mean(0).reshape(shape), rtol=1e-6)
        np.testing.assert_allclose(got["std"], every.std(0).reshape(shape), rtol=1e-5)
        own = [_inverted_cdf(values_of(e).astype(float)) for e in range(store.num_episodes)]
        weighted = sum(q * T for q, T in zip(own, LENGTHS)) / N  # (Q, C)
        for i, q in enumerate(QUANTILES):
            name = f"q{round(q * 100):02d}"
            np.testing.assert_allclose(got[name], weighted[i].reshape(shape), rtol=1e-6)
            for e, ep in enumerate(episodes):  # each episode's own, in meta/episodes
                mine = np.asarray(ep[f"stats/{feature}/{name}"])
                np.testing.assert_allclose(mine, own[e][i].reshape(shape), rtol=1e-6)
        assert episodes[1][f"stats/{feature}/count"] == [LENGTHS[1]]
    assert stats["index"]["max"] == [N - 1] and stats["timestamp"]["max"] == pytest.approx([0.6])


def test_cli_exports_and_refuses_in_one_line(tmp_path, capsys):
    store = _store(tmp_path / "s.zarr")
    out = tmp_path / "out"
    assert main(["store", "export-lerobot", str(store.path), str(out)]) == 0
    assert "4 episodes, 21 frames, 3 tasks at 10 fps" in capsys.readouterr().out
    assert main(["store", "export-lerobot", str(store.path), str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"vla-gr store export-lerobot: error: {out} already exists (use --overwrite "
                   "to replace it)"]  # fmt: skip
    assert main(["store", "export-lerobot", str(tmp_path / "none.zarr"), str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not an episode store" in err[0]
    args = ["store", "export-lerobot", str(store.path), str(out), "--overwrite", "--fps", "5"]
    assert main(args) == 0
    assert json.loads((out / "meta" / "info.json").read_text())["fps"] == 5
    table, _ = _read_data(out)
    assert table["timestamp"].to_pylist()[:3] == pytest.approx([0.0, 0.2, 0.4])


def test_the_frame_rate_must_be_known_and_whole(tmp_path):
    unknown = _store(tmp_path / "a.zarr", info={})
    with pytest.raises(UserError, match="info.control_hz.*--fps"):
        export_lerobot(unknown.path, tmp_path / "a")
    fractional = _store(tmp_path / "b.zarr", info={"control_hz": 7.5})
    with pytest.raises(UserError, match="7.5 Hz"):
        export_lerobot(fractional.path, tmp_path / "b")
    assert export_lerobot(fractional.path, tmp_path / "b", fps=15).fps == 15
    with pytest.raises(StoreError, match="not an episode store"):
        export_lerobot(tmp_path / "missing.zarr", tmp_path / "c")


def test_a_failed_export_leaves_nothing(tmp_path, monkeypatch):
    store = _store(tmp_path / "s.zarr")
    calls = []

    def failing_png(rgb):
        calls.append(1)
        if len(calls) > 8:  # in the second episode
            raise OSError("disk full")
        return png(rgb)

    png = lerobot_export._png
    monkeypatch.setattr(lerobot_export, "_png", failing_png)
    with pytest.raises(OSError, match="disk full"):
        export_lerobot(store.path, tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.zarr"]


@pytest.mark.slow
def test_lerobot_loads_the_export(tmp_path):
    if not LEROBOT_PYTHON.exists():
        pytest.skip("no lerobot virtualenv (.venv-lerobot): run `make lerobot-env`")
    store_path, root = tmp_path / "val.zarr", tmp_path / "lerobot"
    args = ["collect", "--config-name", "config_debug", f"collect.output={store_path}"]
    assert main([*args, "collect.split=val"]) == 0
    store = EpisodeStore.open(store_path)
    export_lerobot(store_path, root, data_file_mb=0.05)  # two data files
    env = os.environ | {"HF_HUB_OFFLINE": "1", "HF_HOME": str(tmp_path / "hf")}
    dump_path = tmp_path / "dump.npz"
    run = [str(LEROBOT_PYTHON), str(READER), str(root), str(dump_path)]
    done = subprocess.run(run, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    dump = np.load(dump_path)
    meta = json.loads(str(dump["meta"]))
    N, E, (H, W) = store.num_frames, store.num_episodes, store.image_size
    assert (meta["codebase_version"], meta["len"], meta["num_episodes"]) == ("v3.0", N, E)
    assert meta["fps"] == store.info["control_hz"] == 10 and meta["data_files"] == 2
    assert meta["shapes"]["observation.image"] == [H, W, 3] and meta["hf_schema_ok"]
    assert meta["camera_keys"] == ["observation.image"]
    ep = np.repeat(np.arange(E), store.episode_lengths)
    assert meta["tasks"] == [store.instruction(e) for e in ep]
    frame = {k[len("frame:") :]: dump[k] for k in dump.files if k.startswith("frame:")}
    image = np.round(frame["observation.image"] * 255).astype(np.uint8)  # (N, 3, H, W)
    np.testing.assert_array_equal(image.transpose(0, 2, 3, 1), store.data_array("rgb")[:N])
    np.testing.assert_array_equal(frame["observation.depth"], store.data_array("depth")[:N])
    np.testing.assert_array_equal(frame["observation.state"], store.data_array("pose")[:N])
    np.testing.assert_array_equal(frame["action"], store.data_array("action")[:N])
    np.testing.assert_array_equal(frame["episode_index"], ep)
    np.testing.assert_array_equal(frame["index"], np.arange(N))
    np.testing.assert_array_equal(dump["ends"], store.episode_ends)
    # Action chunks through delta_timestamps: frames t, t+1, t+2 of the same episode, the
    # ones past its end padded with its last action.
    actions, starts = store.data_array("action")[:N], store.episode_ends - store.episode_lengths
    for i in range(N):
        t, end = frame["frame_index"][i], store.episode_ends[ep[i]]
        rows = np.minimum(starts[ep[i]] + t + np.arange(3), end - 1)
        np.testing.assert_array_equal(dump["chunks"][i], actions[rows])
        np.testing.assert_array_equal(dump["pads"][i], starts[ep[i]] + t + np.arange(3) >= end)
    # meta/stats.json as lerobot parsed it, against lerobot's own statistics of the frames
    # it read: moments equal, quantiles within one bin of lerobot's 5000-bin histograms.
    for key in ("observation.image", "observation.depth", "observation.state", "action"):
        ours = {s: dump[f"meta:{key}:{s}"] for s in ("min", "max", "mean", "std", "count")}
        for s, value in ours.items():
            np.testing.assert_allclose(value, dump[f"lerobot:{key}:{s}"], rtol=1e-9, atol=1e-12)
        bin_width = (ours["max"] - ours["min"]) / 5000
        for q in QUANTILES:
            name = f"q{round(q * 100):02d}"
            gap = np.abs(dump[f"meta:{key}:{name}"] - dump[f"lerobot:{key}:{name}"])
            assert (gap <= bin_width + 1e-6).all(), (key, name, gap.max(), bin_width.max())
