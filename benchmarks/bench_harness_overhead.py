"""What the evaluation harness adds over a bare policy loop, on the same episodes, one process.

    python benchmarks/bench_harness_overhead.py --checkpoint checkpoints/vla_gr_cpu \
        --split val --first 0 --episodes 20 --repeats 3

Per repeat, alternating which goes first, in this one process with one torch thread:

One untimed bare episode first pays the first-use costs (encoder, word tables, scene
compilation). Then:

- **bare**: the README's loop. ``load_policy`` and the env (timed); per episode ``env.reset(options=
  {"episode": i})``, ``policy.reset()``, then ``env.step(policy.select_action(obs))`` until the
  episode ends (a declared outcome ends it through ``env.unwrapped.declare``, as the harness
  does); nothing recorded but the step count and success.
- **harness**: ``vla_gr.evaluation.harness.evaluate`` on the same episodes, ``workers=1``, as
  ``vla-gr eval`` runs it (rows, traces, latencies, ``episodes.jsonl``, ``metrics.json``, the
  report), with the failure videos it renders by default and, as a second line, without them.

Reports seconds, control steps and ms per step of each, the median over repeats and the
harness's overhead as a ratio of medians; both must take the same steps (same decisions).
Writes ``benchmarks/results/bench_harness_overhead.{md,json}`` (``--out``).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
os.environ.setdefault("HF_HUB_OFFLINE", "1")

RESULTS = Path(__file__).resolve().parent / "results"


def bare_loop(checkpoint: str, env_kwargs: dict, episodes: list[int]) -> dict:
    """The README's policy loop over ``episodes``, loading the policy and making the env as a
    script would (both timed, as the harness's are); seconds, steps, successes."""
    from vla_gr.data.collect import make_env
    from vla_gr.policy import load_policy

    steps = successes = 0
    t0 = time.perf_counter()
    policy = load_policy(checkpoint)
    env = make_env(env_kwargs)  # the env the harness builds
    for index in episodes:
        obs, info = env.reset(options={"episode": index})
        policy.reset()
        done = False
        while not done:
            action = policy.select_action(obs)  # (3,)
            outcome = policy.declared_outcome
            if outcome is None:
                obs, _, terminated, truncated, info = env.step(action)
            else:
                obs, _, terminated, truncated, info = env.unwrapped.declare(outcome)
            steps += 1
            done = terminated or truncated
        successes += int(info["success"])
    env.close()
    return {"seconds": time.perf_counter() - t0, "steps": steps, "successes": successes}


def eval_config(args, episodes: list[int], out: str, videos: bool = True):
    """The config ``vla-gr eval checkpoint=... workers=1`` runs on ``episodes``."""
    from vla_gr.configs import DEFAULT_CONFIG
    from vla_gr.evaluate import compose_from_cli

    overrides = [
        f"checkpoint={args.checkpoint}", f"split={args.split}",
        f"first_episode={episodes[0]}", f"num_episodes={len(episodes)}", "workers=1",
        f"output_dir={out}", "eval.progress=false",
    ]  # fmt: skip
    if not videos:
        overrides += ["eval.video_successes=0", "eval.video_per_cause=0"]
    return compose_from_cli(DEFAULT_CONFIG, overrides)[1]


def harness_run(args, episodes: list[int], videos: bool) -> dict:
    """``evaluate`` of the checkpoint on ``episodes`` (workers=1) into a temporary folder."""
    from vla_gr.evaluation.harness import evaluate

    with tempfile.TemporaryDirectory() as out:
        cfg = eval_config(args, episodes, out, videos)
        t0 = time.perf_counter()
        evaluate(cfg)
        seconds = time.perf_counter() - t0
        rows = [json.loads(line) for line in (Path(out) / "episodes.jsonl").open()]
    return {
        "seconds": seconds,
        "steps": sum(len(r["actions"]) for r in rows),
        "successes": sum(int(r["metrics"]["success"]) for r in rows),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument("--split", default="val")
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(RESULTS / "bench_harness_overhead"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    import torch

    from vla_gr.evaluation.harness import plan_episodes
    from vla_gr.machine import describe_machine

    torch.set_num_threads(1)
    episodes = list(range(args.first, args.first + args.episodes))
    _, env_kwargs, _ = plan_episodes(eval_config(args, episodes, tempfile.gettempdir()))
    bare_loop(args.checkpoint, env_kwargs, episodes[:1])  # warm-up, untimed: first-use costs
    kinds = {
        "bare": lambda: bare_loop(args.checkpoint, env_kwargs, episodes),
        "harness": lambda: harness_run(args, episodes, videos=True),
        "harness, no videos": lambda: harness_run(args, episodes, videos=False),
    }
    runs: dict[str, list[dict]] = {name: [] for name in kinds}
    for repeat in range(args.repeats):
        order = list(kinds) if repeat % 2 == 0 else list(kinds)[::-1]
        for name in order:
            runs[name].append(kinds[name]())
            logging.warning("repeat %d %s: %s", repeat, name, runs[name][-1])
    median = {name: statistics.median(r["seconds"] for r in rs) for name, rs in runs.items()}
    steps = {name: sorted({r["steps"] for r in rs}) for name, rs in runs.items()}
    same = len({tuple(s) for s in steps.values()}) == 1
    lines = [
        "# The evaluation harness against a bare policy loop",
        "",
        f"`python benchmarks/bench_harness_overhead.py --checkpoint {args.checkpoint} "
        f"--split {args.split} --first {args.first} --episodes {args.episodes} "
        f"--repeats {args.repeats}`",
        "",
        f"Machine: {describe_machine()}. One process, one torch thread, {args.repeats} "
        "repeats alternating the order; medians.",
        "",
        "| loop | seconds (median) | runs | control steps | ms per step | over bare |",
        "|---|---|---|---|---|---|",
    ]
    for name, rs in runs.items():
        step = rs[0]["steps"]
        each = " / ".join(f"{r['seconds']:.1f}" for r in rs)
        lines.append(
            f"| {name} | {median[name]:.1f} | {each} | {step} | "
            f"{1e3 * median[name] / step:.2f} | {median[name] / median['bare'] - 1:+.1%} |"
        )
    lines += [
        "",
        f"Same control steps in every run: {'yes' if same else 'NO: ' + str(steps)}; "
        f"successes {runs['bare'][0]['successes']} / {runs['harness'][0]['successes']} of "
        f"{args.episodes} (bare / harness).",
    ]
    text = "\n".join(lines) + "\n"
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text(text)
    out.with_suffix(".json").write_text(
        json.dumps({"args": vars(args), "runs": runs, "median_seconds": median,
                    "same_steps": same, "machine": describe_machine()}, indent=1) + "\n"
    )  # fmt: skip
    print(text)


if __name__ == "__main__":
    main()
