"""Export an episode store as a LeRobotDataset folder (codebase version v3.0, as read by
``lerobot`` 0.4's ``LeRobotDataset(repo_id, root=folder)``), written with pyarrow only.

Layout written (paths and columns as lerobot's own writer makes them)::

    meta/info.json                         codebase_version, fps, features, totals, paths
    meta/stats.json                        per feature: min max mean std count q01 q10 q50 q90 q99
    meta/tasks.parquet                     one row per distinct instruction (task_index)
    meta/episodes/chunk-000/file-000.parquet   one row per episode: its frame range, data
                                           file, task, per-episode stats, and ours: the
                                           episode's index in its split, spec and metrics (JSON)
    data/chunk-CCC/file-FFF.parquet        one row per frame, episodes in store order; a new
                                           file once one holds ``data_file_mb`` (lerobot: 100)

Frame features: ``observation.image`` (H, W, 3) RGB as embedded PNG (lossless: what the
loader decodes is the stored uint8 image / 255), ``observation.depth`` (H, W, 1) float32
metres, ``observation.state`` (3,) the pose (x, y, yaw) from the episode start, ``action``
(3,) (v, w, stop), the instruction as the frame's task, and lerobot's ``timestamp`` (frame
index / fps, fps = the env's control rate), ``frame_index``, ``episode_index`` (store order),
``index`` and ``task_index``. The goal and distractor masks are not exported: they are
labels from the simulator's segmentation, not observations.

Statistics follow lerobot's rules: per episode, each feature over its frames (images per
channel, scaled to [0, 1], shaped (3, 1, 1); depth over all pixels, shaped (1,)); the dataset's
are the episodes' merged exactly (min, max, mean, std) and their quantiles averaged weighted
by frame counts, as lerobot's ``aggregate_stats`` does. ``count`` is a number of frames (all
of them; lerobot's writer computes image statistics on a sample of an episode's frames).

pyarrow comes with the ``lerobot`` extra (``pip install 'vla-gr[lerobot]'``).
"""

from __future__ import annotations

import io
import json
import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from vla_gr.data.normalize import compute_stats, merge_stats
from vla_gr.data.store import EpisodeStore
from vla_gr.errors import UserError

log = logging.getLogger(__name__)

__all__ = [
    "CODEBASE_VERSION",
    "LeRobotExport",
    "aggregate_stats",
    "episode_stats",
    "export_lerobot",
    "features",
]

CODEBASE_VERSION = "v3.0"
QUANTILES: tuple[float, ...] = (0.01, 0.10, 0.50, 0.90, 0.99)
CHUNKS_SIZE = 1000  # files per chunk folder (lerobot's DEFAULT_CHUNK_SIZE)
DATA_FILE_MB = 100  # lerobot's DEFAULT_DATA_FILE_SIZE_IN_MB
VIDEO_FILE_MB = 200  # lerobot's default; written to info.json, no video is written
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH = "data/" + CHUNK_FILE + ".parquet"
EPISODES_PATH = "meta/episodes/" + CHUNK_FILE + ".parquet"
VIDEO_PATH = "videos/{video_key}/" + CHUNK_FILE + ".mp4"
ROBOT_TYPE = "vla_gr_diff_drive"
#: Module of the ``datasets`` library's ArrayND arrow extension types (their registered names).
HF_EXTENSIONS = "datasets.features.features"
#: Store frame key -> exported feature.
FRAME_FEATURES = {
    "rgb": "observation.image",
    "depth": "observation.depth",
    "pose": "observation.state",
    "action": "action",
}
#: lerobot's DEFAULT_FEATURES: what every frame carries besides the recorded ones.
INDEX_FEATURES = {
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}


@dataclass(frozen=True)
class LeRobotExport:
    """What ``export_lerobot`` wrote."""

    path: Path
    episodes: int
    frames: int
    tasks: int
    data_files: int
    fps: int


def features(image_size: tuple[int, int]) -> dict[str, dict]:
    """The ``info.json`` features of an export of ``image_size`` (H, W) images."""
    H, W = image_size
    pixels = ["height", "width", "channels"]
    out = {
        "observation.image": {"dtype": "image", "shape": [H, W, 3], "names": pixels},
        "observation.depth": {"dtype": "float32", "shape": [H, W, 1], "names": pixels},
        "observation.state": {"dtype": "float32", "shape": [3], "names": ["x", "y", "yaw"]},
        "action": {
            "dtype": "float32",
            "shape": [3],
            "names": ["linear_velocity", "angular_velocity", "stop"],
        },
    }
    return out | {k: {"dtype": d, "shape": [1], "names": None} for k, d in INDEX_FEATURES.items()}


def _hf_features(feats: dict[str, dict]) -> dict:
    """The same features as the ``datasets`` library (4.x) describes them in a parquet
    schema's ``huggingface`` metadata, so its own readers decode images and arrays too."""
    out = {}
    for key, ft in feats.items():
        shape = ft["shape"]
        if ft["dtype"] == "image":
            out[key] = {"_type": "Image"}
        elif shape == [1]:
            out[key] = {"dtype": ft["dtype"], "_type": "Value"}
        elif len(shape) == 1:
            value = {"dtype": ft["dtype"], "_type": "Value"}
            out[key] = {"feature": value, "length": shape[0], "_type": "List"}
        else:
            out[key] = {"shape": shape, "dtype": ft["dtype"], "_type": f"Array{len(shape)}D"}
    return out


def _arrow():
    """pyarrow and pyarrow.parquet, or a one-line error saying how to install them."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise UserError(
            "exporting a LeRobotDataset needs pyarrow: pip install 'vla-gr[lerobot]'"
        ) from None
    return pa, pq


def episode_stats(frames: dict[str, np.ndarray], feats: dict[str, dict]) -> dict[str, dict]:
    """lerobot's per-episode statistics of ``frames`` (feature -> (T, ...) array).

    Returns ``{feature: {stat: np.ndarray}}`` with the stats of lerobot's
    ``compute_episode_stats`` plus the mergeable moments under ``"_moments"`` (see
    ``normalize.compute_stats``). A quantile q is the smallest value with at least a
    fraction q of the values at or below it (numpy's ``inverted_cdf``): what lerobot's
    histogram estimates, to within one of its 5000 bins.
    """
    out = {}
    for key, x in frames.items():
        T = x.shape[0]
        values = x.reshape(-1, x.shape[-1]) if x.ndim > 1 else x.reshape(-1, 1)  # (n, C)
        moments = compute_stats(values)
        quantiles = np.quantile(values, QUANTILES, axis=0, method="inverted_cdf")  # (Q, C)
        stats = _moment_stats(moments) | {_qname(q): quantiles[i] for i, q in enumerate(QUANTILES)}
        stats = _as_feature(stats, feats[key])
        out[key] = stats | {"count": np.array([T], dtype=np.int64), "_moments": moments}
    return out


def _qname(q: float) -> str:
    return f"q{round(q * 100):02d}"


def _moment_stats(moments: dict) -> dict[str, np.ndarray]:
    """min, max, mean, std (C,) of a ``normalize.compute_stats`` dict."""
    return {k: np.asarray(moments[k], dtype=np.float64) for k in ("min", "max", "mean", "std")}


def _as_feature(stats: dict[str, np.ndarray], feature: dict) -> dict[str, np.ndarray]:
    """Statistics (C,) as lerobot keeps them for ``feature``: an image's per channel in
    [0, 1], shaped (3, 1, 1); anything else as it is."""
    if feature["dtype"] != "image":
        return stats
    return {k: (v / 255.0).reshape(-1, 1, 1) for k, v in stats.items()}


def aggregate_stats(per_episode: list[dict[str, dict]], feats: dict[str, dict]) -> dict:
    """The dataset's statistics from its episodes' (``episode_stats``): min, max, mean and
    std of all frames (merged moments), quantiles averaged weighted by frame counts."""
    out = {}
    for key in per_episode[0]:
        eps = [ep[key] for ep in per_episode]
        counts = np.array([ep["count"][0] for ep in eps], dtype=np.float64)  # (E,)
        moments = None
        for ep in eps:
            moments = merge_stats(moments, ep["_moments"])
        stats = _as_feature(_moment_stats(moments), feats[key])
        for q in map(_qname, QUANTILES):
            stacked = np.stack([ep[q] for ep in eps])  # (E, *shape)
            weights = counts.reshape(-1, *([1] * (stacked.ndim - 1)))
            stats[q] = (stacked * weights).sum(0) / counts.sum()
        out[key] = stats | {"count": np.array([int(counts.sum())], dtype=np.int64)}
    return out


def _jsonable(stats: dict[str, np.ndarray]) -> dict[str, list]:
    return {k: v.tolist() for k, v in stats.items() if not k.startswith("_")}


def _png(rgb: np.ndarray) -> bytes:
    """PNG bytes of one (H, W, 3) uint8 image."""
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG")
    return buffer.getvalue()


def _nested(pa, x: np.ndarray):
    """(T, *shape) array -> a length-T arrow array of nested variable-size lists (the storage
    of ``datasets``' ArrayND features)."""
    values = pa.array(x.reshape(-1))
    for size in reversed(x.shape[1:]):
        offsets = np.arange(0, len(values) + 1, size, dtype=np.int32)
        values = pa.ListArray.from_arrays(pa.array(offsets), values)
    return values


def _frame_table(pa, schema, frames: dict[str, np.ndarray]):
    """One episode's rows as an arrow table of ``schema``."""
    columns = []
    for field in schema:
        x = frames[field.name]
        if pa.types.is_struct(field.type):  # an image
            images = pa.array([_png(img) for img in x], type=pa.binary())
            paths = pa.nulls(len(x), type=pa.string())
            columns.append(pa.StructArray.from_arrays([images, paths], names=["bytes", "path"]))
        elif pa.types.is_fixed_size_list(field.type):
            columns.append(pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1]))
        elif pa.types.is_list(field.type):
            columns.append(_nested(pa, x))
        else:
            columns.append(pa.array(x, type=field.type))
    return pa.Table.from_arrays(columns, schema=schema)


def _frame_schema(pa, feats: dict[str, dict]):
    """The data files' schema, typed as the ``datasets`` library types lerobot's features: an
    image is a {bytes, path} struct, a vector a fixed-size list, an (H, W, C) array nested
    lists tagged as its ``ArrayND`` extension type (readers with ``datasets`` get that type)."""
    fields = []
    for key, ft in feats.items():
        shape, dtype, tags = ft["shape"], ft["dtype"], None
        if dtype == "image":
            kind = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
        elif shape == [1]:
            kind = pa.from_numpy_dtype(np.dtype(dtype))
        elif len(shape) == 1:
            kind = pa.list_(pa.from_numpy_dtype(np.dtype(dtype)), shape[0])
        else:
            kind = pa.from_numpy_dtype(np.dtype(dtype))
            for _ in shape:
                kind = pa.list_(kind)
            tags = {
                "ARROW:extension:name": f"{HF_EXTENSIONS}.Array{len(shape)}DExtensionType",
                "ARROW:extension:metadata": json.dumps([shape, dtype]),
            }
        fields.append(pa.field(key, kind, metadata=tags))
    hf = json.dumps({"info": {"features": _hf_features(feats)}})
    return pa.schema(fields, metadata={"huggingface": hf})


def _tasks_table(pa, tasks: list[str]):
    """``meta/tasks.parquet`` as pandas' ``to_parquet`` writes lerobot's tasks frame (the task
    string is its index), so ``pandas.read_parquet`` gives lerobot the same frame."""
    pandas_meta = {
        "index_columns": ["__index_level_0__"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": None,
                "field_name": "__index_level_0__",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "attributes": {},
        "creator": {"library": "pyarrow", "version": pa.__version__},
    }
    return pa.table(
        {
            "task_index": pa.array(range(len(tasks)), type=pa.int64()),
            "__index_level_0__": pa.array(tasks, type=pa.string()),
        }
    ).replace_schema_metadata({"pandas": json.dumps(pandas_meta)})


def _fps_of(store: EpisodeStore, fps: int | None) -> int:
    """The export's frame rate: ``fps`` or the store's control rate (a whole number)."""
    if fps is not None:
        if int(fps) != fps or fps < 1:
            raise UserError(f"--fps must be a whole number of frames per second >= 1, got {fps}")
        return int(fps)
    rate = store.info.get("control_hz")
    if rate is None:
        raise UserError(
            f"store {store.path} does not record its control rate (info.control_hz): "
            "give the frame rate with --fps"
        )
    if float(rate) != int(rate) or int(rate) < 1:
        raise UserError(
            f"a LeRobotDataset has a whole number of frames per second; store {store.path} "
            f"runs at {rate} Hz: give one with --fps"
        )
    return int(rate)


class _DataFiles:
    """The ``data/`` parquet files: episodes appended in order, a new file (and, after
    ``CHUNKS_SIZE`` files, a new chunk folder) once a file holds ``limit_mb`` of rows."""

    def __init__(self, pq, root: Path, schema, limit_mb: float) -> None:
        self._pq, self._root, self._schema = pq, root, schema
        self._limit = limit_mb * 2**20
        self._writer, self._bytes = None, 0
        self.chunk, self.file, self.count = 0, -1, 0

    def write(self, table) -> tuple[int, int]:
        """Append one episode's rows; returns the (chunk, file) index they went to."""
        if self._writer is not None and self._bytes + table.nbytes > self._limit:
            self.close()
        if self._writer is None:
            self.file += 1
            if self.file == CHUNKS_SIZE:
                self.chunk, self.file = self.chunk + 1, 0
            path = self._root / DATA_PATH.format(chunk_index=self.chunk, file_index=self.file)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = self._pq.ParquetWriter(path, self._schema, compression="snappy")
            self._bytes, self.count = 0, self.count + 1
        self._writer.write_table(table)
        self._bytes += table.nbytes
        return self.chunk, self.file

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None


def _episode_frames(store: EpisodeStore, e: int, start: int, task: int, fps: int) -> dict:
    """Stored episode ``e`` as exported features -> (T, ...) arrays; its first frame is the
    dataset's frame ``start``."""
    stored = store.episode(e, keys=tuple(FRAME_FEATURES))
    T = len(stored["action"])
    frames = {FRAME_FEATURES[k]: v for k, v in stored.items()}
    return frames | {
        "timestamp": (np.arange(T) / fps).astype(np.float32),  # (T,)
        "frame_index": np.arange(T, dtype=np.int64),  # (T,)
        "episode_index": np.full(T, e, dtype=np.int64),  # (T,)
        "index": np.arange(start, start + T, dtype=np.int64),  # (T,)
        "task_index": np.full(T, task, dtype=np.int64),  # (T,)
    }


def export_lerobot(
    src: str | Path,
    dst: str | Path,
    *,
    fps: int | None = None,
    overwrite: bool = False,
    data_file_mb: float = DATA_FILE_MB,
) -> LeRobotExport:
    """Write the committed episodes of store ``src`` as a LeRobotDataset folder ``dst``.

    ``fps`` defaults to the store's control rate (``info.control_hz``). The folder is built
    under a temporary sibling name and renamed into place: ``dst`` is never half written.
    Raises ``FileExistsError`` when ``dst`` exists and ``overwrite`` is False, ``StoreError``
    for a missing or damaged store.
    """
    pa, pq = _arrow()
    dst = Path(dst)
    if dst.exists() and not overwrite:
        raise FileExistsError(f"{dst} already exists (use --overwrite to replace it)")
    store = EpisodeStore.open(src, mode="r")
    if store.num_episodes == 0:
        raise UserError(f"store {store.path} holds no episodes: nothing to export")
    rate = _fps_of(store, fps)
    feats = features(store.image_size)
    schema = _frame_schema(pa, feats)
    building = dst.with_name(f".{dst.name}.exporting-{os.getpid()}")
    if building.exists():
        shutil.rmtree(building)
    data = _DataFiles(pq, building, schema, data_file_mb)
    tasks: dict[str, int] = {}
    rows, per_episode, start = [], [], 0
    try:
        for e in range(store.num_episodes):
            instruction = store.instruction(e)
            task = tasks.setdefault(instruction, len(tasks))
            frames = _episode_frames(store, e, start, task, rate)
            T = len(frames["index"])
            chunk, file = data.write(_frame_table(pa, schema, frames))
            stats = episode_stats(frames, feats)
            per_episode.append(stats)
            row = {
                "episode_index": e,
                "tasks": [instruction],
                "length": T,
                "data/chunk_index": chunk,
                "data/file_index": file,
                "dataset_from_index": start,
                "dataset_to_index": start + T,
                "meta/episodes/chunk_index": 0,
                "meta/episodes/file_index": 0,
                "vla_gr/episode_index": int(store.episode_indices[e]),
                "vla_gr/spec": json.dumps(store.spec(e), sort_keys=True),
                "vla_gr/metrics": json.dumps(store.metrics(e), sort_keys=True),
            }
            for key, values in stats.items():
                row |= {f"stats/{key}/{k}": v for k, v in _jsonable(values).items()}
            rows.append(row)
            start += T
        data.close()
        _write_meta(pa, pq, building, rows, list(tasks), feats, per_episode, rate, data_file_mb)
    except BaseException:
        data.close()
        shutil.rmtree(building, ignore_errors=True)
        raise
    if dst.exists():
        shutil.rmtree(dst) if dst.is_dir() else dst.unlink()
    os.replace(building, dst)
    result = LeRobotExport(dst, len(rows), start, len(tasks), data.count, rate)
    log.info(
        "exported %s to LeRobotDataset %s: %d episodes, %d frames, %d tasks, %d data files",
        store.path,
        dst,
        result.episodes,
        result.frames,
        result.tasks,
        result.data_files,
    )
    return result


def _write_meta(pa, pq, root, rows, tasks, feats, per_episode, fps, data_file_mb) -> None:
    """meta/info.json, meta/stats.json, meta/tasks.parquet and meta/episodes."""
    E, N = len(rows), rows[-1]["dataset_to_index"]
    info = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": ROBOT_TYPE,
        "total_episodes": E,
        "total_frames": N,
        "total_tasks": len(tasks),
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": data_file_mb,
        "video_files_size_in_mb": VIDEO_FILE_MB,
        "fps": fps,
        "splits": {"train": f"0:{E}"},
        "data_path": DATA_PATH,
        "video_path": None,
        "features": feats,
    }
    meta = root / "meta"
    (meta / "episodes").mkdir(parents=True, exist_ok=True)
    (meta / "info.json").write_text(json.dumps(info, indent=4) + "\n", encoding="utf-8")
    stats = {k: _jsonable(v) for k, v in aggregate_stats(per_episode, feats).items()}
    (meta / "stats.json").write_text(json.dumps(stats, indent=4) + "\n", encoding="utf-8")
    pq.write_table(_tasks_table(pa, tasks), meta / "tasks.parquet")
    episodes = pa.Table.from_pylist(rows)
    path = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(episodes, path, compression="snappy")
