"""Read a LeRobotDataset folder with lerobot's own ``LeRobotDataset`` and dump what it reads.

Runs in the lerobot virtualenv (``make lerobot-env``), not the project's: ``python
lerobot_read.py ROOT OUT.npz``. The slow test of ``test_lerobot_export.py`` compares the dump
with the episode store it exported. The dump holds every frame as ``LeRobotDataset.__getitem__``
returns it, the metadata lerobot parsed, action chunks through ``delta_timestamps``, and the
dataset statistics recomputed with lerobot's own functions from the frames it read.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from datasets import Features
from lerobot.datasets.compute_stats import aggregate_stats, get_feature_stats
from lerobot.datasets.lerobot_dataset import CODEBASE_VERSION, LeRobotDataset
from lerobot.datasets.utils import get_hf_features_from_features

KEYS = ("observation.image", "observation.depth", "observation.state", "action")
SCALARS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
CHUNK = 3  # frames of the action chunks read through delta_timestamps


def lerobot_stats(frames: dict[str, np.ndarray], ends: np.ndarray) -> dict:
    """Dataset statistics as lerobot computes them: per episode (``get_feature_stats`` with
    the axes of ``compute_episode_stats``), then ``aggregate_stats``."""
    per_episode, start = [], 0
    for end in ends:
        ep = {}
        for key, x in frames.items():
            # float64: lerobot's statistics square their input in its own dtype (a uint8 or
            # float32 square loses the variance).
            x = x[start:end].astype(np.float64)
            if key == "observation.image":  # (T, 3, H, W) in [0, 1] -> pixel units as lerobot
                stats = get_feature_stats(np.round(x * 255), axis=(0, 2, 3), keepdims=True)
                ep[key] = {
                    k: v if k == "count" else np.squeeze(v / 255.0, 0) for k, v in stats.items()
                }
            else:
                ep[key] = get_feature_stats(x, axis=0, keepdims=x.ndim == 1)
        per_episode.append(ep)
        start = end
    return aggregate_stats(per_episode)


def main(root: str, out: str) -> None:
    ds = LeRobotDataset("vla_gr/export", root=root)
    items = [ds[i] for i in range(len(ds))]
    frames = {k: np.stack([item[k].numpy() for item in items]) for k in (*KEYS, *SCALARS)}
    tasks = [item["task"] for item in items]
    ends = np.array([ep["dataset_to_index"] for ep in ds.meta.episodes], dtype=np.int64)
    deltas = {"action": [i / ds.fps for i in range(CHUNK)]}  # seconds ahead
    chunked = LeRobotDataset("vla_gr/export", root=root, delta_timestamps=deltas)
    chunks = np.stack([chunked[i]["action"].numpy() for i in range(len(chunked))])
    pads = np.stack([chunked[i]["action_is_pad"].numpy() for i in range(len(chunked))])
    data_files = sorted(Path(root, "data").glob("*/*.parquet"))
    hf_schema_ok = all(
        Features.from_arrow_schema(pq.read_schema(f)) == get_hf_features_from_features(ds.features)
        for f in data_files
    )
    meta = {
        "codebase_version": CODEBASE_VERSION,
        "len": len(ds),
        "num_episodes": ds.num_episodes,
        "fps": ds.fps,
        "total_tasks": ds.meta.total_tasks,
        "shapes": {k: list(v) for k, v in ds.meta.shapes.items()},
        "camera_keys": ds.meta.camera_keys,
        "tasks": tasks,
        "data_files": len(data_files),
        "hf_schema_ok": hf_schema_ok,
    }
    arrays = {f"frame:{k}": v for k, v in frames.items()}
    arrays |= {"ends": ends, "chunks": chunks, "pads": pads}
    for source, stats in (("meta", ds.meta.stats), ("lerobot", lerobot_stats(frames, ends))):
        for key, values in stats.items():
            arrays |= {f"{source}:{key}:{k}": np.asarray(v) for k, v in values.items()}
    np.savez(out, meta=json.dumps(meta), **arrays)


if __name__ == "__main__":
    main(*sys.argv[1:3])
