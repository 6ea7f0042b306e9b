"""Latency of the agent's parts in closed loop, batch 1, one thread: S1 and S2 of the dual system.

    python benchmarks/bench_agent_latency.py --checkpoint checkpoints/vla_gr_cpu \
        [--episodes 5] [--split val] [--repeats 3] [--variant learned_s1=s1.kind=learned ...]

Runs the checkpoint (and each ``--variant name=override[,override...]`` of it) on the same
``--episodes`` episodes of ``--split`` with one torch thread, ``--repeats`` times, and reports
the median over the repeats of each p50 / p95 / p99 in ms (with the range of p95) of:
``decision`` (one ``select_action``, everything the agent does per control step), ``s1``
(S1's share of a step: a chunk action from the queue or a new S1 decision),
``s1_network`` (the learned S1's forward + sampling, on the steps it runs) and ``s2`` (one
planner tick), split into ``s2_perception`` (the goal head) and ``s2_navigator`` (the GR-field
navigator), and the navigator's GR-field update into its stages (``field.mapping``,
``field.poisson``, ``field.fast_marching``, ...: ``GRField.last_timings``). Writes
``<out>.json`` and ``<out>.md``. Run it on a quiet machine: a benchmark taken beside another
job is noise.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from vla_gr.data.collect import make_env
from vla_gr.evaluation.agents import PolicyAgent
from vla_gr.evaluation.runner import run_episode
from vla_gr.machine import describe_machine, machine_line
from vla_gr.policy import VLAGRPolicy

logger = logging.getLogger("bench_agent_latency")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_agent_latency"
PARTS = ("decision", "s1", "s1_network", "s2", "s2_perception", "s2_navigator")


def timed_s1(policy: VLAGRPolicy, sink: list[float]) -> None:
    """Record the wall time (ms) of every learned-S1 network call of ``policy`` in ``sink``."""
    act = policy.s1.act

    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        out = act(*args, **kwargs)
        sink.append((time.perf_counter() - t0) * 1e3)
        return out

    policy.s1.act = wrapper


def timed_field(policy: VLAGRPolicy, sink: dict[str, list[float]]) -> None:
    """After every navigator tick of ``policy``, append its GR-field update's stage times (ms)
    to ``sink["field.<stage>"]``, and on ticks the local planner planned, its time to
    ``sink["local_plan"]``."""
    navigator = policy.dual_system.navigator
    plan = navigator.plan

    def wrapper(*args, **kwargs):
        out = plan(*args, **kwargs)
        for stage, seconds in navigator.field.last_timings.items():
            sink.setdefault(f"field.{stage}", []).append(seconds * 1e3)
        local = getattr(navigator, "local", None)
        if local is not None and local.last_plan_seconds > 0:
            sink.setdefault("local_plan", []).append(local.last_plan_seconds * 1e3)
        return out

    navigator.plan = wrapper


def measure(
    checkpoint: str, overrides: list[str], env_kwargs: dict, episodes: int, first: int = 0
) -> dict:
    """Per-part latency quantiles (ms) and the success of each episode, for one variant."""
    policy = VLAGRPolicy.from_pretrained(checkpoint, overrides=overrides)
    network: list[float] = []
    timed_s1(policy, network)
    field: dict[str, list[float]] = {}
    timed_field(policy, field)
    env = make_env(env_kwargs)
    samples: dict[str, list[float]] = {p: [] for p in PARTS}
    successes = []
    try:
        for k in range(first, first + episodes):
            row = run_episode(env, PolicyAgent(policy), k)
            for part, values in row["latency_ms"].items():
                samples.setdefault(part, []).extend(values)
            successes.append(bool(row["metrics"]["success"]))
    finally:
        env.close()
    samples["s1_network"] = network
    samples.update(field)
    result = {"success": float(np.mean(successes)), "episodes": episodes}
    for part, values in samples.items():
        if values:
            q = np.percentile(values, [50, 95, 99])
            result[part] = {"n": len(values), "p50": q[0], "p95": q[1], "p99": q[2]}
    result["s1_parameters"] = sum(p.numel() for p in policy.s1.parameters())
    result["s1_kind"] = policy.config.s1.kind
    return result


def median_of_repeats(runs: list[dict]) -> dict:
    """One variant's result from its repeated ``measure`` runs: per part, the median over the
    runs of p50 / p95 / p99 and the range of p95 (``p95_min``, ``p95_max``)."""
    result = dict(runs[0])
    for part, q in runs[0].items():
        if not isinstance(q, dict):
            continue
        per_run = [r[part] for r in runs if part in r]
        result[part] = {
            "n": q["n"],
            **{k: float(np.median([x[k] for x in per_run])) for k in ("p50", "p95", "p99")},
            "p95_min": min(x["p95"] for x in per_run),
            "p95_max": max(x["p95"] for x in per_run),
        }
    result["repeats"] = len(runs)
    result["success"] = float(np.mean([r["success"] for r in runs]))
    return result


def table(results: dict) -> str:
    lines = [
        "| variant | S1 | S1 params | part | calls | p50 ms | p95 ms | p95 range | p99 ms |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        stages = [key for key in r if key.startswith("field.")]  # in GRField's own order
        for part in (*PARTS, *stages, "local_plan"):
            if part in r:
                q = r[part]
                lines.append(
                    f"| {name} | {r['s1_kind']} | {r['s1_parameters']:,} | {part} | {q['n']} | "
                    f"{q['p50']:.2f} | {q['p95']:.2f} | "
                    f"{q.get('p95_min', q['p95']):.2f}-{q.get('p95_max', q['p95']):.2f} | "
                    f"{q['p99']:.2f} |"
                )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument("--variant", action="append", default=[], help="name=key=value[,...]")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--split", default="val")
    parser.add_argument("--first", type=int, default=0, help="first episode index")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3, help="runs per variant (medians)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads)
    variants = {"vla_gr": []}
    for item in args.variant:
        name, _, overrides = item.partition("=")
        variants[name] = [o for o in overrides.split(",") if o]
    env_kwargs = {"split": args.split, "semantic": False}
    if args.repeats < 1:
        parser.error(f"--repeats={args.repeats} must be >= 1")
    results = {
        name: median_of_repeats(
            [measure(args.checkpoint, overrides, env_kwargs, args.episodes, args.first)
             for _ in range(args.repeats)]
        )
        for name, overrides in variants.items()
    }  # fmt: skip
    meta = {
        "checkpoint": args.checkpoint,
        "split": args.split,
        "first": args.first,
        "threads": args.threads,
        "repeats": args.repeats,
        "machine": describe_machine(),
    }
    out = {"meta": meta, "results": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(out, indent=2) + "\n")
    text = (
        f"# Agent latency, batch 1, {args.threads} thread(s)\n\n"
        f"`python benchmarks/bench_agent_latency.py --checkpoint {args.checkpoint} "
        f"--episodes {args.episodes} --first {args.first} --split {args.split} "
        f"--repeats {args.repeats}`"
        + "".join(f" `--variant {v}`" for v in args.variant)
        + f"\n\n{machine_line(meta['machine'])}\n\n{table(results)}\n"
    )
    args.out.with_suffix(".md").write_text(text)
    logger.info("\n%s", table(results))
    return out


if __name__ == "__main__":
    main()
