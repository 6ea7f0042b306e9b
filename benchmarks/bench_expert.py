"""Geodesic expert on N episodes of a split: SR, SPL, soft-SPL, collision rate, throughput.

    python benchmarks/bench_expert.py --episodes 100 --split val --workers 2

Episodes k = 0..N-1 (``env.reset(seed=k)``) are split across worker processes (one env
each); the final ``info`` of every episode is aggregated with ``vla_gr.envs.metrics``. Writes
``<out>.json`` (per-episode infos + aggregate) and ``<out>.md`` (the table).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import numpy as np  # noqa: E402

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
            obs, info = env.reset(seed=k)
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


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--split", default="val")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--image-size", type=int, default=64)
    parser.add_argument("--noise-std", type=float, default=0.0)
    parser.add_argument("--noise-prob", type=float, default=0.0)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="path stem for .json/.md")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.episodes < 1 or args.workers < 1:
        parser.error("--episodes and --workers must be >= 1")

    from vla_gr.envs.metrics import aggregate, format_table

    workers = min(args.workers, args.episodes)
    chunks = [list(range(args.episodes))[w::workers] for w in range(workers)]
    job = (args.split, args.image_size, args.noise_std, args.noise_prob)
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
    summary["env_steps_per_s"] = total_steps / wall
    name = f"expert ({args.split}, noise {args.noise_std}/{args.noise_prob})"
    table = format_table({name: summary})
    failures = [
        {k: i.get(k) for k in ("episode_index", "episode_id", "distance_to_goal", "steps")}
        for i in infos
        if not i["success"]
    ]
    print(table)
    if failures:
        print(f"failures: {failures}")

    args.out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "command": "python benchmarks/bench_expert.py " + " ".join(argv or sys.argv[1:]),
        "args": {k: _relative(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs",
        "wall_s": wall,
    }
    payload = {"meta": meta, "summary": summary, "failures": failures, "episodes": infos}
    args.out.with_suffix(".json").write_text(json.dumps(_jsonable(payload), indent=1) + "\n")
    md = [
        "# Geodesic expert benchmark",
        "",
        f"`{meta['command'].strip()}` on {meta['machine']}; {workers} worker process(es), "
        f"wall {wall:.0f} s.",
        "",
        table,
        "",
        "Targets (issue 2): SR >= 0.99, SPL >= 0.90, collision rate <= 0.01 on 100 val episodes.",
    ]
    if failures:
        md += ["", f"Failures: {json.dumps(_jsonable(failures))}"]
    args.out.with_suffix(".md").write_text("\n".join(md) + "\n")
    logger.info("wrote %s.{json,md}", args.out)
    return summary


if __name__ == "__main__":
    main()
