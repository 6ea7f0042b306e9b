"""GR field speed: one full update (map + mass + Poisson + fast marching + path) + features.

    python benchmarks/bench_gr_field.py --sizes 128 256 --repeats 50 --threads 1

Feeds analytic depth images of a 9 m x 7 m box room (64 x 64, HFOV 79 deg) seen from a robot
that turns and drives around the start, with a goal patch on one wall, into ``GRField`` at
batch 1. Reports medians (and p90) of the full ``update()`` and of each of its parts
(``GRField.last_timings``: mapping, masses, Poisson, metric, fast marching, path) and of
reading the egocentric features, which the field computes on first access (with the full
potential behind them); "full update" includes that read.
Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import time
from pathlib import Path

import numpy as np
import torch

from vla_gr.core.gr_field import GRField, GRFieldConfig
from vla_gr.geometry.camera import box_room_depth
from vla_gr.machine import describe_machine, machine_line

logger = logging.getLogger("bench_gr_field")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_gr_field"
ROOM = (-3.0, 6.0, -3.0, 4.0)  # x0, x1, y0, y1 (m)
PARTS = ("mapping", "masses", "poisson", "metric", "fast_marching", "path", "features")


def room_depth(pose, n: int, hfov: float = 79.0, camera_height: float = 0.88) -> np.ndarray:
    """Analytic z-depth (n, n) of the box room with a floor seen from ``pose`` (x, y, yaw)."""
    return np.minimum(box_room_depth(pose, ROOM, n, hfov, camera_height), 9.99)


def trajectory(steps: int) -> list[tuple[float, float, float]]:
    """Poses turning a full circle while drifting 1.5 m forward."""
    return [(1.5 * k / steps, 0.3 * math.sin(k / 5), 2 * math.pi * k / steps) for k in range(steps)]


def stats(times: list[float]) -> dict:
    ms = np.asarray(times) * 1e3
    return {"median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90))}


def bench_size(size: int, cell: float, image: int, repeats: int, margin: float) -> dict:
    """Time a sequence of updates at one map size; returns medians per part."""
    cfg = GRFieldConfig(map_size=size, cell_size=cell, planning_margin=margin)
    field = GRField(cfg)
    poses = trajectory(repeats + 5)
    frames = [
        {
            "depth": torch.from_numpy(room_depth(p, image))[None, ..., None],
            "pose": torch.tensor([p], dtype=torch.float32),
        }
        for p in poses
    ]
    goal = torch.zeros(1, image, image)
    goal[0, : image // 2, : image // 8] = 1.0  # a strip of wall, floor to ceiling
    full: list[float] = []
    parts: dict[str, list[float]] = {}
    windows: list[int] = []
    for k, obs in enumerate(frames):
        t0 = time.perf_counter()
        out = field.update(obs, goal)
        t1 = time.perf_counter()
        _ = out.features  # computed on first read: timed as a part of the full update
        elapsed = time.perf_counter() - t0
        if k < 5:  # warm-up (kernel caches, allocator)
            continue
        full.append(elapsed)
        windows.append(int(np.prod(field.planning_windows[0])))
        for name, seconds in field.last_timings.items():
            parts.setdefault(name, []).append(seconds)
        parts.setdefault("features", []).append(elapsed - (t1 - t0))
    return {
        "map_size": size,
        "cell_size": cell,
        "image_size": image,
        "planning_margin": margin,
        "fmm_window_cells_median": int(np.median(windows)),
        "updates": len(full),
        "has_path_last": bool(out.has_path[0]),
        "goal_seen_last": bool(out.goal_seen[0]),
        "full_update": stats(full),
        "parts": {name: stats(times) for name, times in parts.items()},
    }


def to_markdown(results: dict) -> str:
    lines = [
        "# GR field update speed (CPU, batch 1)",
        "",
        f"`{results['command']}`",
        "",
        f"{machine_line(results['machine'])} Torch threads: {results['threads']}; "
        f"load average before / after: {results['load_before']} / {results['load_after']}.",
        "",
        "| map cells | cell (m) | FMM window (cells) | full update median (p90) ms | "
        + " | ".join(f"{p} ms" for p in PARTS)
        + " | goal <= 20 ms |",
        "|---|---|---|---|" + "---|" * len(PARTS) + "---|",
    ]
    for r in results["sizes"]:
        full = r["full_update"]
        lines.append(
            f"| {r['map_size']}² | {r['cell_size']} | {r['fmm_window_cells_median']} "
            f"| {full['median_ms']:.1f} ({full['p90_ms']:.1f})"
            + "".join(f" | {r['parts'][p]['median_ms']:.2f}" for p in PARTS)
            + f" | {'yes' if full['median_ms'] <= 20 else 'no'} |"
        )
    lines += [
        "",
        "FMM window: fast marching runs on the explored bounding box grown by",
        "`planning_margin` (3 m by default; median cells shown). The rows with the whole map",
        "as window (`planning_margin` 1000 m) give the cost once a whole map is explored.",
        "",
        "Parts are medians of `GRField.last_timings` over the same updates: mapping (depth ->",
        "points -> evidence map, free-space rays), masses (goal, frontier, obstacles), poisson",
        "(zero-padded 2H x 2W FFT convolution), metric (obstacle distance transform, psi, cost,",
        "goal stand-off), fast_marching (robot-radius inflation, scikit-fmm travel time, upwind",
        "gradient), path (sub-cell descent, resampling); features (read after the update: the",
        f"full potential's Poisson solve and the egocentric grid_sample of {results['features']}).",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--cell-size", type=float, default=0.15)
    parser.add_argument("--image-size", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(args.threads)
    load_before = [round(x, 2) for x in os.getloadavg()]
    sizes = []
    runs = [(size, margin) for size in args.sizes for margin in (3.0, 1000.0)]
    for size, margin in runs:
        r = bench_size(size, args.cell_size, args.image_size, args.repeats, margin)
        logger.info("%d^2: full %.2f ms, poisson %.2f ms, fast marching %.2f ms", size,
                    r["full_update"]["median_ms"], r["parts"]["poisson"]["median_ms"],
                    r["parts"]["fast_marching"]["median_ms"])  # fmt: skip
        sizes.append(r)
    from vla_gr.core.gr_field import FEATURE_NAMES

    results = {
        "command": "python benchmarks/bench_gr_field.py "
        + " ".join(
            f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, list) else v}"
            for k, v in vars(args).items()
            if k != "out"
        ),  # fmt: skip
        "machine": describe_machine(),
        "threads": args.threads,
        "load_before": load_before,
        "load_after": [round(x, 2) for x in os.getloadavg()],
        "features": ", ".join(FEATURE_NAMES),
        "sizes": sizes,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(results, indent=2) + "\n")
    args.out.with_suffix(".md").write_text(to_markdown(results))
    return results


if __name__ == "__main__":
    main()
