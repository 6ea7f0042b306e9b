"""Geodesic expert on N episodes of a split: SR, SPL, soft-SPL, collision rate, throughput.

    python benchmarks/bench_expert.py --episodes 100 --split val --workers 2

Episodes k = 0..N-1 (``env.reset(options={"episode": k})``) are split across worker processes
(one env each); the final ``info`` of every episode is aggregated with ``vla_gr.envs.metrics``.
Writes ``<out>.json`` (per-episode infos + aggregate) and ``<out>.md`` (the table).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import numpy as np  # noqa: E402

from vla_gr.machine import describe_machine, machine_line  # noqa: E402

logger = logging.getLogger("bench_expert")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_expert"


def _relative(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT.parent))
    except ValueError:
        return str(path)


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def run_episodes(
    indices: list[int],
    split: str,
    image_size: int,
    noise_std: float,
    noise_prob: float,
) -> list[dict]:
    """Run the expert on episodes ``indices`` in one env; return their final infos."""
    import gymnasium as gym

    import vla_gr.envs  # noqa: F401  (registers VLAGR/ObjectNav-v0)
    from vla_gr.envs.expert import GeodesicExpert

    env = gym.make("VLAGR/ObjectNav-v0", split=split, image_size=image_size)
    results = []
    try:
        for k in indices:
            expert = GeodesicExpert(env, noise_std=noise_std, noise_prob=noise_prob, seed=k)
            t0 = time.perf_counter()
            obs, info = env.reset(options={"episode": k})
            expert.reset()
            steps = 0
            terminated = truncated = False
            while not (terminated or truncated):
                obs, _, terminated, truncated, info = env.step(expert.act(obs))
                steps += 1
            final = {key: _jsonable(v) for key, v in info.items()}
            final.setdefault("steps", steps)
            final["episode_index"] = k
            final["stopped"] = bool(terminated)
            final["wall_s"] = time.perf_counter() - t0
            results.append(final)
    finally:
        env.close()
    return results


def _noise_setting(text: str) -> tuple[float, float]:
    try:
        std, prob = (float(x) for x in text.split(","))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"--noise wants STD,PROB, got {text!r}") from err
    return std, prob


def run_setting(args, workers: int, noise: tuple[float, float]) -> dict:
    """All episodes under one noise setting; returns summary, failures and per-episode infos."""
    from vla_gr.envs.metrics import aggregate

    chunks = [list(range(args.episodes))[w::workers] for w in range(workers)]
    job = (args.split, args.image_size, *noise)
    t0 = time.perf_counter()
    if workers == 1:
        infos = run_episodes(chunks[0], *job)
    else:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(run_episodes, chunk, *job) for chunk in chunks]
            infos = [info for f in futures for info in f.result()]
    wall = time.perf_counter() - t0
    infos.sort(key=lambda i: i["episode_index"])
    summary = aggregate(infos)
    total_steps = int(sum(i["steps"] for i in infos))
    summary["steps_per_episode"] = total_steps / len(infos)
    summary["episodes_per_min"] = 60.0 * len(infos) / wall
    failures = [
        {k: i.get(k) for k in ("episode_index", "episode_id", "distance_to_goal", "steps")}
        for i in infos
        if not i["success"]
    ]
    return {
        "noise_std": noise[0],
        "noise_prob": noise[1],
        "wall_s": wall,
        "summary": summary,
        "failures": failures,
        "episodes": infos,
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--split", default="val")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--image-size", type=int, default=64)
    parser.add_argument(
        "--noise",
        type=_noise_setting,
        action="append",
        help="STD,PROB of DART noise; repeat for several rows (default: 0,0 only)",
    )
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="path stem for .json/.md")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.episodes < 1 or args.workers < 1:
        parser.error("--episodes and --workers must be >= 1")
    settings = args.noise or [(0.0, 0.0)]

    from vla_gr.envs.metrics import format_table

    workers = min(args.workers, args.episodes)
    runs = [run_setting(args, workers, noise) for noise in settings]
    rows = {
        f"expert {args.split}, noise {r['noise_std']:g}/{r['noise_prob']:g}": r["summary"]
        for r in runs
    }
    table = format_table(rows)
    print(table)
    for r in runs:
        if r["failures"]:
            print(f"failures (noise {r['noise_std']:g}/{r['noise_prob']:g}): {r['failures']}")

    args.out.parent.mkdir(parents=True, exist_ok=True)
    command = "python benchmarks/bench_expert.py " + " ".join(argv or sys.argv[1:])
    meta = {
        "command": command.strip(),
        "args": {k: _relative(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "machine": describe_machine(),
        "workers": workers,
    }
    payload = {"meta": meta, "runs": runs}
    args.out.with_suffix(".json").write_text(json.dumps(_jsonable(payload), indent=1) + "\n")
    md = [
        "# Geodesic expert benchmark",
        "",
        f"`{meta['command']}`: {workers} worker process(es), 64x64 RGB-D rendered every step. "
        "Noise = DART std on (v, w) / excursion probability.",
        "",
        machine_line(meta["machine"]),
        "",
        table,
        "",
        "Targets (issue 2, noise-free): SR >= 0.99, SPL >= 0.90, collision rate <= 0.01.",
    ]
    for r in runs:
        if r["failures"]:
            md += ["", f"Failures (noise {r['noise_std']:g}/{r['noise_prob']:g}): "]
            md += [f"- {json.dumps(_jsonable(f))}" for f in r["failures"]]
    args.out.with_suffix(".md").write_text("\n".join(md) + "\n")
    logger.info("wrote %s.{json,md}", args.out)
    return {name: r["summary"] for name, r in zip(rows, runs)}


if __name__ == "__main__":
    main()
