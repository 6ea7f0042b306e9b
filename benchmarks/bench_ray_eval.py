"""``eval.backend=ray`` throughput: the same episodes with 1 and with 2 Ray workers in one run.

    python benchmarks/bench_ray_eval.py --checkpoint checkpoints/vla_gr_cpu --episodes 6

One Ray cluster (``--address``; default: a local one of 2 CPUs started here) serves both runs,
so its start is in neither. Each run is ``vla-gr eval`` through the harness (``evaluate``) with
``eval.backend=ray``; its time is metrics.json's ``timing.seconds``: the whole episode loop,
the workers' start (imports, env, agent) included, as a user waits for it. The ratio is
episodes/min with 2 workers over 1. The same episodes also run on the local backend (2 spawned
workers) and the rows are compared (latency aside): the backends must agree exactly.
Writes ``results/bench_ray_eval.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from vla_gr.machine import describe_machine, machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_ray_eval"


def run(cfg, backend: str, workers: int, out: Path) -> tuple[dict, list[dict]]:
    """(throughput row, episode rows without latency) of one ``evaluate``."""
    from vla_gr.evaluate import evaluate

    sub = dataclasses.replace(cfg.eval, backend=backend, workers=workers, output_dir=str(out))
    metrics = evaluate(dataclasses.replace(cfg, eval=sub))
    lines = (out / "episodes.jsonl").read_text().splitlines()
    rows = [{k: v for k, v in json.loads(x).items() if k != "latency_ms"} for x in lines]
    m, t = metrics["metrics"], metrics["timing"]
    row = {
        "backend": backend,
        "workers": workers,
        "episodes": m["episodes"],
        "success": m["success"],
        "spl": m["spl"],
        "mean_steps": m["steps"],
        "seconds": t["seconds"],
        "episodes_per_min": t["episodes_per_min"],
    }
    return row, rows


def write_results(result: dict, out: Path) -> str:
    r1, r2 = result["runs"][0], result["runs"][1]
    lines = [
        "# bench_ray_eval",
        "",
        f"`{result['command']}`",
        "",
        f"{result['episodes']} `{result['split']}` episodes of `{result['checkpoint']}` from "
        f"{result['first_episode']}, one Ray cluster for both runs ({result['cluster']}). "
        "The machine has **2 cores shared with other jobs**: the Ray workers, the driver, the "
        "Ray processes and whatever else runs share them, so the figures are noisy and a "
        "second worker cannot give 2x here.",
        "",
        machine_line(result["machine"]),
        "",
        "| backend | workers | episodes | SR | SPL | mean steps | seconds | episodes/min |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in result["runs"]:
        lines.append(
            f"| {r['backend']} | {r['workers']} | {r['episodes']} | {r['success']:.2f} | "
            f"{r['spl']:.3f} | {r['mean_steps']:.0f} | {r['seconds']:.1f} | "
            f"{r['episodes_per_min']:.1f} |"
        )
    lines += [
        "",
        f"**Ratio, 2 Ray workers over 1: {result['ratio_2_over_1']:.2f}x episodes/min** "
        f"({r2['episodes_per_min']:.1f} / {r1['episodes_per_min']:.1f}), measured in one run; "
        "each time includes the workers' start (imports, env, loading the agent).",
        "",
        f"Rows identical (latency aside) between Ray with 1 worker, Ray with 2 and the local "
        f"backend: {'yes' if result['same_rows'] else 'NO'}.",
    ]
    table = "\n".join(lines) + "\n"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(table)
    return table


def main(argv=None) -> int:
    import ray

    from vla_gr.configs import load_config

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument("--split", default="val")
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--address", default=None, help="a Ray cluster (default: a local one)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    overrides = [
        f"eval.checkpoint={args.checkpoint}",
        "eval.agent=checkpoint",
        f"eval.split={args.split}",
        f"eval.first_episode={args.first}",
        f"eval.num_episodes={args.episodes}",
        "eval.progress=false",
        "eval.video_successes=0",
        "eval.video_per_cause=0",
    ]
    cfg = load_config("config_cpu", overrides)[1]
    quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
    if args.address:
        ray.init(address=args.address, **quiet)
        cluster = f"at {args.address}"
    else:
        ray.init(address="local", num_cpus=2, include_dashboard=False, **quiet)
        cluster = "a local cluster of 2 CPUs"
    runs, rows = [], []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for backend, workers in (("ray", 1), ("ray", 2), ("local", 2)):
                row, episode_rows = run(cfg, backend, workers, Path(tmp) / f"{backend}{workers}")
                runs.append(row)
                rows.append(episode_rows)
    finally:
        ray.shutdown()
    result = {
        "command": "python benchmarks/bench_ray_eval.py " + " ".join(argv or sys.argv[1:]),
        "checkpoint": args.checkpoint,
        "split": args.split,
        "first_episode": args.first,
        "episodes": args.episodes,
        "cluster": cluster,
        "runs": runs,
        "ratio_2_over_1": runs[1]["episodes_per_min"] / runs[0]["episodes_per_min"],
        "same_rows": rows[0] == rows[1] == rows[2],
        "machine": describe_machine(),
    }
    sys.stdout.write(write_results(result, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
