"""ObjectNav env throughput: env.step with RGB-D, expert episodes per minute, collection.

    python benchmarks/bench_env.py                 # full run, writes results/bench_env.{json,md}
    python benchmarks/bench_env.py --runs 3 --steps 300 --out /tmp/bench_env   # quicker

Rows (each the median of ``--runs`` timed runs after a warm-up):
- ``env.step`` at 64x64 and 128x128 RGB-D, in one process (``gymnasium.make``) and as a
  vector of 2 (``gymnasium.make_vec``, sync and async); steps/s counts env steps (a vector
  step of 2 envs is 2). Actions drive forward while turning; episodes autoreset.
- the same at 64x64 with instance segmentation (what data collection records);
- geodesic expert episodes per minute (one process, ``val`` episodes 0..N-1);
- collection frames/s of ``vla_gr.data.collect.collect`` (expert + zarr store, 1 and 2
  worker processes), if that module is importable.
The machine is shared: the JSON records the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

from vla_gr.envs import ENV_ID  # noqa: E402  (importing registers the env id)
from vla_gr.machine import describe_machine, machine_line  # noqa: E402

logger = logging.getLogger("bench_env")
ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_env"


def _actions(n: int, num_envs: int | None) -> list[np.ndarray]:
    """Deterministic drive-and-turn actions (n, [num_envs,] 3) that never call STOP."""
    t = np.arange(n, dtype=np.float32)
    acts = np.stack([np.full(n, 0.6), np.sin(t / 7.0), np.full(n, -1.0)], axis=1)  # (n, 3)
    acts = acts.astype(np.float32)
    if num_envs is None:
        return list(acts)
    return list(np.repeat(acts[:, None, :], num_envs, axis=1))  # n x (num_envs, 3)


def time_single(image_size: int, steps: int, runs: int, semantic: bool = False) -> list[float]:
    """Steps/s of one ``gymnasium.make`` env, one value per run."""
    env = gym.make(ENV_ID, image_size=image_size, semantic=semantic)
    env.reset(options={"episode": 0})
    acts = _actions(steps, None)
    rates = []
    for run in range(runs + 1):  # run 0 warms up (scene compile, GL context)
        t0 = time.perf_counter()
        for a in acts:
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
        rate = steps / (time.perf_counter() - t0)
        if run > 0:
            rates.append(rate)
    env.close()
    return rates


def time_vector(image_size: int, steps: int, runs: int, mode: str, num_envs: int = 2):
    """Env steps/s of a ``gymnasium.make_vec`` vector (``mode`` sync/async), per run."""
    vec = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode=mode, image_size=image_size)
    vec.reset(seed=0)
    acts = _actions(steps, num_envs)
    rates = []
    for run in range(runs + 1):
        t0 = time.perf_counter()
        for a in acts:
            vec.step(a)
        rate = steps * num_envs / (time.perf_counter() - t0)
        if run > 0:
            rates.append(rate)
    vec.close()
    return rates


def time_expert(episodes: int, runs: int) -> tuple[list[float], dict]:
    """Expert episodes/min on ``val`` episodes 0..episodes-1 per run, and the metrics."""
    from vla_gr.envs import GeodesicExpert
    from vla_gr.envs.metrics import aggregate

    env = gym.make(ENV_ID, image_size=64)
    expert = GeodesicExpert(env)
    rates, infos, steps = [], [], 0
    for run in range(runs + 1):
        infos, steps = [], 0
        t0 = time.perf_counter()
        for k in range(episodes if run > 0 else 1):
            obs, info = env.reset(options={"episode": k})
            expert.reset()
            done = False
            while not done:
                obs, _, term, trunc, info = env.step(expert.act(obs))
                done = term or trunc
            infos.append(info)
            steps += info["steps"]
        if run > 0:
            rates.append(episodes * 60.0 / (time.perf_counter() - t0))
    env.close()
    summary = {k: float(v) for k, v in aggregate(infos).items() if isinstance(v, int | float)}
    summary["mean_steps"] = steps / episodes
    return rates, summary


def time_collect(episodes: int, workers: int, runs: int) -> list[float] | None:
    """Frames/s of ``vla_gr.data.collect.collect`` into a temporary store, per run."""
    try:
        from vla_gr.configs import load_config
        from vla_gr.data.collect import collect
    except ImportError as err:
        logger.warning("collection row left out: %s", err)
        return None
    rates = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as tmp:
            _, cfg = load_config(
                "config_cpu",
                [
                    f"collect.output={tmp}/store.zarr",
                    f"collect.num_episodes={episodes}",
                    f"collect.workers={workers}",
                    "collect.split=val",
                    "collect.progress=false",
                ],
            )
            rates.append(collect(cfg)["frames_per_s"])
    return rates


def _row(name: str, unit: str, rates: list[float], **extra) -> dict:
    return {
        "name": name,
        "unit": unit,
        "median": statistics.median(rates),
        "runs": [round(r, 2) for r in rates],
        **extra,
    }


def format_markdown(result: dict) -> str:
    """The results as a Markdown table with a header describing the machine."""
    m = result["machine"]
    lines = [
        "# bench_env: ObjectNav env throughput",
        "",
        f"`{result['command']}`  ",
        f"{machine_line(m)} MuJoCo {m['mujoco']}, MUJOCO_GL={m['mujoco_gl']}, "
        f"LP_NUM_THREADS={m['lp_num_threads']}, load average {m['load_before']} before / "
        f"{m['load_after']} after.",
        "",
        "| benchmark | median | unit | runs |",
        "|---|---:|---|---|",
    ]
    for row in result["rows"]:
        runs = ", ".join(f"{r:.0f}" for r in row["runs"])
        lines.append(f"| {row['name']} | {row['median']:.0f} | {row['unit']} | {runs} |")
    if result.get("expert_metrics"):
        em = result["expert_metrics"]
        lines += [
            "",
            f"Expert on the timed episodes: SR {em.get('success', 0):.3f}, SPL "
            f"{em.get('spl', 0):.3f}, {em.get('mean_steps', 0):.0f} steps per episode.",
        ]
    for note in result["notes"]:
        lines += ["", note]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per row (median)")
    parser.add_argument("--steps", type=int, default=1000, help="env steps per timed run")
    parser.add_argument("--expert-episodes", type=int, default=10)
    parser.add_argument("--collect-episodes", type=int, default=24)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--skip-collect", action="store_true")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output path stem")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")

    load_before = [round(x, 2) for x in os.getloadavg()]
    rows, notes = [], []
    for size in args.sizes:
        rows.append(
            _row(
                f"env.step RGB-D {size}x{size}, 1 process",
                "steps/s",
                time_single(size, args.steps, args.runs),
            )
        )
        for mode in ("sync", "async"):
            rows.append(
                _row(
                    f"env.step RGB-D {size}x{size}, {mode} vector of 2",
                    "steps/s",
                    time_vector(size, args.steps // 2, args.runs, mode),
                )
            )
        print(rows[-3:], flush=True)
    rows.append(
        _row(
            "env.step RGB-D + segmentation 64x64, 1 process",
            "steps/s",
            time_single(64, args.steps, args.runs, semantic=True),
        )
    )
    expert_rates, expert_metrics = time_expert(args.expert_episodes, max(1, args.runs // 2))
    rows.append(
        _row(
            f"expert episodes ({args.expert_episodes} val episodes, 1 process)",
            "episodes/min",
            expert_rates,
        )
    )
    if args.skip_collect:
        notes.append("Collection rows skipped (--skip-collect).")
    else:
        for workers in (1, 2):
            rates = time_collect(args.collect_episodes, workers, max(1, args.runs // 2))
            if rates is None:
                notes.append("Collection rows left out: vla_gr.data.collect is not importable.")
                break
            rows.append(
                _row(
                    f"collection ({args.collect_episodes} val episodes, {workers} worker(s))",
                    "frames/s",
                    rates,
                )
            )
    notes.append(
        "Vector rows count env steps (2 per vector step). Async workers are separate "
        "processes, so on 2 cores they can exceed one process; sync runs both envs in one."
    )
    notes.append(
        "Timed runs cross episode ends (autoreset at max_episode_steps=1000), so successive "
        "runs are other episodes (start poses, houses): their spread is mostly what is in "
        "view, not noise."
    )
    import mujoco

    result = {
        "command": "python benchmarks/bench_env.py " + " ".join(argv or sys.argv[1:]),
        "machine": describe_machine()
        | {
            "mujoco": mujoco.__version__,
            "mujoco_gl": os.environ.get("MUJOCO_GL"),
            "lp_num_threads": os.environ.get("LP_NUM_THREADS"),
            "load_before": load_before,
            "load_after": [round(x, 2) for x in os.getloadavg()],
        },
        "rows": rows,
        "expert_metrics": expert_metrics,
        "notes": notes,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    table = format_markdown(result)
    args.out.with_suffix(".md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
