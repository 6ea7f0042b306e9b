"""``vla-gr eval`` throughput, and the harness overhead over a bare rollout loop.

    python benchmarks/bench_eval.py --episodes 8 --max-steps 300

Rows: episodes/min and env steps/s of ``evaluate`` for the ``expert`` and a trained tiny
checkpoint (``config_debug`` recipe, trained here for 2 steps unless ``--checkpoint``)
with 1 and 2 workers (loop time only: no report). The tiny checkpoint calls STOP within a
few steps, so it also runs as ``checkpoint_nostop`` (its STOP output ignored): full-length
episodes at the same cost per decision. Overhead: the same env and agent run
the same episodes once through a bare ``env.step(agent.act(obs))`` loop and once through
the harness's ``run_episode`` (per-step record, latency, causes), interleaved ``--rounds``
times, best CPU time of each (process time: less sensitive than wall time to other jobs on
a shared machine); the bare loop without semantic rendering is shown too.
Writes ``results/bench_eval.json`` and ``.md`` (with the load average: a shared machine).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch  # noqa: E402

from vla_gr.machine import describe_machine, machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_eval"
AGENTS = ("expert", "checkpoint", "checkpoint_nostop")


class NoStop:
    """Wraps an agent and ignores its STOP (the episode runs to its budget)."""

    def __init__(self, agent) -> None:
        self.agent = agent

    def reset(self, seed=None) -> None:
        self.agent.reset(seed)

    def act(self, obs):
        action = self.agent.act(obs).copy()  # (3,)
        action[2] = -1.0
        return action

    def parameters(self) -> dict:
        return self.agent.parameters()


def _register_nostop() -> None:
    """Module level, so that spawned workers (which import this script) know it too."""
    from vla_gr.evaluation.agents import AGENTS as REGISTRY
    from vla_gr.evaluation.agents import make_agent

    if "checkpoint_nostop" not in REGISTRY:
        REGISTRY["checkpoint_nostop"] = lambda cfg, env: NoStop(make_agent("checkpoint", cfg, env))


_register_nostop()


def tiny_checkpoint(tmp: Path, image_size: int) -> Path:
    """Train the ``config_debug`` agent for 2 steps; its ``best`` checkpoint."""
    from vla_gr import cli

    args = [
        f"env.image_size={image_size}",
        f"training.dataset={tmp / 'syn.zarr'}",
        f"training.output_dir={tmp / 'runs'}",
        "training.run_name=bench",
        "logging.tensorboard=false",
    ]
    if cli.main(["train", "--config-name", "config_debug", *args]) != 0:
        raise RuntimeError("training the tiny checkpoint failed")
    return tmp / "runs" / "bench" / "checkpoints" / "best"


def base_config(args, checkpoint: Path, out: Path):
    from vla_gr.configs import load_config

    overrides = [
        f"env.image_size={args.image_size}",
        f"env.max_episode_steps={args.max_steps}",
        f"eval.num_episodes={args.episodes}",
        f"eval.checkpoint={checkpoint}",
        f"eval.output_dir={out}",
        "eval.progress=false",
        "eval.video_successes=0",
        "eval.video_per_cause=0",
    ]
    return load_config("config_debug", overrides)[1]


def throughput(cfg, agent: str, workers: int, out: Path) -> dict:
    """Episodes/min and steps/s of one ``evaluate`` run (loop time from metrics.json)."""
    from vla_gr.evaluate import evaluate

    sub = dataclasses.replace(cfg.eval, agent=agent, workers=workers, output_dir=str(out))
    metrics = evaluate(dataclasses.replace(cfg, eval=sub))
    seconds = metrics["timing"]["seconds"]
    steps = metrics["metrics"]["steps"] * metrics["metrics"]["episodes"]
    return {
        "agent": agent,
        "workers": workers,
        "episodes": metrics["metrics"]["episodes"],
        "success": metrics["metrics"]["success"],
        "mean_steps": metrics["metrics"]["steps"],
        "seconds": seconds,
        "episodes_per_min": metrics["timing"]["episodes_per_min"],
        "steps_per_s": steps / seconds,
        "decision_p50_ms": metrics["latency_ms"]["decision"]["p50"],
    }


def bare_loop(env, agent, indices) -> int:
    """The minimal rollout: reset, then ``env.step(agent.act(obs))`` until done; steps."""
    steps = 0
    with torch.inference_mode():
        for k in indices:
            obs, _ = env.reset(options={"episode": k})
            agent.reset(k)
            done = False
            while not done:
                obs, _, terminated, truncated, _ = env.step(agent.act(obs))
                done = terminated or truncated
                steps += 1
    return steps


def harness_loop(env, agent, indices) -> int:
    from vla_gr.evaluation.runner import run_episode

    return sum(run_episode(env, agent, k)["metrics"]["steps"] for k in indices)


def overhead(cfg, agent_name: str, rounds: int, episodes: int) -> dict:
    """Best-of-``rounds`` CPU seconds of the bare loop and of the harness, same episodes."""
    from vla_gr.data.collect import make_env
    from vla_gr.evaluate import plan_episodes
    from vla_gr.evaluation.agents import make_agent

    torch.set_num_threads(1)
    indices, env_kwargs, _ = plan_episodes(cfg)
    indices = indices[:episodes]
    times: dict[str, list[float]] = {"bare_no_semantic": [], "bare": [], "harness": []}
    steps = {}
    envs = {
        "bare_no_semantic": make_env({**env_kwargs, "semantic": False}),
        "bare": make_env(env_kwargs),
    }
    envs["harness"] = envs["bare"]
    agents = {name: make_agent(agent_name, cfg, env) for name, env in envs.items()}
    loops = {"bare_no_semantic": bare_loop, "bare": bare_loop, "harness": harness_loop}
    try:
        bare_loop(envs["bare"], agents["bare"], indices[:1])  # warm up scenes and kernels
        bare_loop(envs["bare_no_semantic"], agents["bare_no_semantic"], indices[:1])
        for _ in range(rounds):
            for name, loop in loops.items():
                t0 = time.process_time()  # CPU time of this process (all its threads):
                steps[name] = loop(envs[name], agents[name], indices)  # robust to other load
                times[name].append(time.process_time() - t0)
    finally:
        envs["bare"].close()
        envs["bare_no_semantic"].close()
    best = {name: min(t) for name, t in times.items()}
    return {
        "agent": agent_name,
        "steps": steps,
        "seconds": best,
        "all_seconds": times,
        "harness_overhead": best["harness"] / best["bare"] - 1.0,
        "semantic_cost": best["bare"] / best["bare_no_semantic"] - 1.0,
    }


def write_results(result: dict, out: Path) -> str:
    lines = [
        "# bench_eval",
        "",
        f"{result['episodes']} val episodes, {result['image_size']}² RGB-D, budget "
        f"{result['max_steps']} steps; load average before/after: "
        f"{result['loadavg_before']} / {result['loadavg_after']}.",
        "",
        machine_line(result["machine"]),
        "",
        "| agent | workers | SR | mean steps | episodes/min | steps/s | decision p50 (ms) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in result["throughput"]:
        lines.append(
            f"| {r['agent']} | {r['workers']} | {r['success']:.2f} | {r['mean_steps']:.0f} | "
            f"{r['episodes_per_min']:.1f} | {r['steps_per_s']:.0f} | {r['decision_p50_ms']:.2f} |"
        )
    lines += [
        "",
        f"Harness overhead: CPU seconds, best of {result['rounds']} interleaved rounds on "
        f"{result['overhead_episodes']} episodes, same env and agent.",
        "",
        "| agent | bare loop, no semantic (CPU s) | bare loop (CPU s) | harness (CPU s) | "
        "harness overhead |",
        "|---|---|---|---|---|",
    ]
    for o in result["overhead"]:
        s = o["seconds"]
        lines.append(
            f"| {o['agent']} | {s['bare_no_semantic']:.2f} | {s['bare']:.2f} | "
            f"{s['harness']:.2f} | {100 * o['harness_overhead']:+.1f}% |"
        )
    table = "\n".join(lines) + "\n"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(table)
    return table


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument("--image-size", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--overhead-episodes", type=int, default=6)
    parser.add_argument("--checkpoint", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    before = [round(x, 2) for x in os.getloadavg()]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        checkpoint = args.checkpoint or tiny_checkpoint(tmp, args.image_size)
        cfg = base_config(args, checkpoint, tmp / "eval")
        runs = [
            throughput(cfg, agent, workers, tmp / f"{agent}-{workers}")
            for agent in AGENTS
            for workers in (1, 2)
        ]
        over = [overhead(cfg, agent, args.rounds, args.overhead_episodes) for agent in AGENTS]
    result = {
        "episodes": args.episodes,
        "max_steps": args.max_steps,
        "image_size": args.image_size,
        "rounds": args.rounds,
        "overhead_episodes": args.overhead_episodes,
        "checkpoint": str(args.checkpoint or "config_debug, 2 training steps"),
        "throughput": runs,
        "overhead": over,
        "loadavg_before": before,
        "loadavg_after": [round(x, 2) for x in os.getloadavg()],
        "machine": describe_machine(),
    }
    sys.stdout.write(write_results(result, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
