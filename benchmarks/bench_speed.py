"""Today's code against a reference commit, side by side in one run: S2's tick and evaluation
throughput of the same checkpoint on the same episodes, and whether the decisions are the same.

    python benchmarks/bench_speed.py --reference 5c86971 [--checkpoint checkpoints/vla_gr_cpu] \
        [--episodes 10 --first 100 --split val --repeats 3] [--eval-episodes 20] \
        [--out benchmarks/results/bench_speed]

The reference is a git commit (checked out once into a worktree under ``--worktrees``) or a
folder holding a ``src/`` tree. A relative ``--checkpoint`` is each code's own (the folder of
that path in its tree: the reference runs the checkpoint as it was at its commit);
``--today-checkpoint`` gives today's code another one (a latency-budget setting). Each repeat
runs both codes in fresh processes, alternating which goes first, with one torch thread: the
agent on ``--episodes`` episodes of ``--split`` from ``--first``
(``bench_agent_latency.measure``: the tick is all of S2's work for a step, reading, perception,
field and local planner), then, when ``--eval-episodes`` > 0, ``vla-gr eval`` of those episodes
with 2 workers (episodes per minute, wall clock of the command). Quoted: per code, the median
over repeats of each part's p50 / p95, and the ratios reference / today of those medians.
Decisions: the per-episode outcomes and the largest difference of any action between the codes.
Writes ``<out>.json`` and ``<out>.md``. Run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

logger = logging.getLogger("bench_speed")

ROOT = Path(__file__).resolve().parent
REPO = ROOT.parent
DEFAULT_OUT = ROOT / "results" / "bench_speed"
PARTS = ("s2", "s2_perception", "s2_navigator", "decision")

# what a child process runs: the agent on the episodes, latencies and actions to a JSON file
_CHILD = """
import json, sys, torch
sys.path.insert(0, {bench!r})
from bench_agent_latency import timed_field
from vla_gr.data.collect import make_env
from vla_gr.evaluation.agents import PolicyAgent
from vla_gr.evaluation.runner import run_episode
from vla_gr.policy import VLAGRPolicy
torch.set_num_threads(1)
policy = VLAGRPolicy.from_pretrained({checkpoint!r})
field = {{}}
timed_field(policy, field)
env = make_env({{"split": {split!r}, "semantic": False}})
samples, episodes = {{}}, []
for k in range({first}, {first} + {episodes}):
    row = run_episode(env, PolicyAgent(policy), k)
    for part, values in row["latency_ms"].items():
        samples.setdefault(part, []).extend(values)
    actions = [list(map(float, a)) for a in row["actions"]]
    episodes.append({{"index": k, "success": bool(row["metrics"]["success"]),
                      "cause": row["cause"], "actions": actions}})
env.close()
samples.update(field)
json.dump({{"samples": samples, "episodes": episodes}}, open({out!r}, "w"))
"""


def source_tree(reference: str, worktrees: Path) -> Path:
    """The ``src`` folder of ``reference``: a folder with ``src/``, or a commit checked out
    (once) into a worktree under ``worktrees``."""
    folder = Path(reference)
    if (folder / "src" / "vla_gr").is_dir():
        return folder / "src"
    commit = subprocess.run(
        ["git", "-C", str(REPO), "rev-parse", "--short", f"{reference}^{{commit}}"],
        capture_output=True, text=True,
    )  # fmt: skip
    if commit.returncode != 0:
        raise SystemExit(f"--reference {reference!r} is neither a folder with src/ nor a commit")
    tree = worktrees / f"vla_gr_{commit.stdout.strip()}"
    if not tree.exists():
        subprocess.run(
            ["git", "-C", str(REPO), "worktree", "add", "--detach", str(tree), reference],
            check=True, capture_output=True,
        )  # fmt: skip
    return tree / "src"


def _env(src: Path) -> dict:
    """The environment of a child process that imports ``vla_gr`` from ``src``."""
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.setdefault("MUJOCO_GL", "egl")
    env.setdefault("HF_HUB_OFFLINE", "1")
    return env


def checkpoint_of(src: Path, checkpoint: Path) -> Path:
    """``checkpoint`` as the code in ``src`` has it: a relative path is in its own tree."""
    return checkpoint if checkpoint.is_absolute() else src.parent / checkpoint


def run_agent(src: Path, checkpoint: Path, args) -> dict:
    """Latency samples (ms) per part and per-episode outcomes/actions of the code in ``src``
    running ``checkpoint``."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "agent.json"
        code = _CHILD.format(
            bench=str(ROOT), checkpoint=str(checkpoint), split=args.split,
            first=args.first, episodes=args.episodes, out=str(out),
        )  # fmt: skip
        subprocess.run([sys.executable, "-c", code], env=_env(src), check=True, cwd=REPO)
        return json.loads(out.read_text())


def run_eval(src: Path, checkpoint: Path, args) -> float:
    """Episodes per minute of ``vla-gr eval`` (2 workers) of the code in ``src`` running
    ``checkpoint``."""
    with tempfile.TemporaryDirectory() as tmp:
        command = [
            sys.executable, "-m", "vla_gr.cli", "eval",
            f"checkpoint={checkpoint}",
            f"split={args.split}", f"first_episode={args.first}",
            f"num_episodes={args.eval_episodes}", "workers=2", f"output_dir={tmp}/eval",
            "eval.progress=false",
        ]  # fmt: skip
        t0 = time.perf_counter()
        subprocess.run(command, env=_env(src), check=True, cwd=REPO, capture_output=True)
        return args.eval_episodes / ((time.perf_counter() - t0) / 60.0)


def quantiles(samples: dict) -> dict:
    """{part: {"n", "p50", "p95"}} of one run's samples."""
    out = {}
    for part, values in samples.items():
        if values:
            p50, p95 = np.percentile(values, [50, 95])
            out[part] = {"n": len(values), "p50": float(p50), "p95": float(p95)}
    return out


def decisions(reference: list[dict], today: list[dict]) -> dict:
    """Outcomes per episode and the largest action difference between the two codes."""
    differ = [r["index"] for r, t in zip(reference, today) if r["cause"] != t["cause"]]
    largest = 0.0
    for r, t in zip(reference, today):
        a, b = np.asarray(r["actions"]), np.asarray(t["actions"])  # (T, 3) each
        n = min(len(a), len(b))
        if n:
            largest = max(largest, float(np.abs(a[:n] - b[:n]).max()))
        if len(a) != len(b):
            largest = float("inf")
    return {"episodes_with_other_outcome": differ, "max_action_difference": largest}


def summarise(runs: list[dict]) -> dict:
    """Per part, the median over repeats of p50 and p95 (and the range of p95)."""
    out = {}
    for part in {p for r in runs for p in r}:
        per = [r[part] for r in runs if part in r]
        out[part] = {
            "n": per[0]["n"],
            "p50": float(np.median([q["p50"] for q in per])),
            "p95": float(np.median([q["p95"] for q in per])),
            "p95_range": [min(q["p95"] for q in per), max(q["p95"] for q in per)],
        }
    return out


def table(result: dict) -> str:
    ref, new = result["reference"]["latency"], result["today"]["latency"]
    lines = [
        "| part | calls | reference p50 / p95 ms | today p50 / p95 ms | p50 ratio | p95 ratio |",
        "|---|---|---|---|---|---|",
    ]
    parts = [*PARTS, *sorted(p for p in ref if p.startswith("field.")), "local_plan"]
    for part in parts:
        if part in ref and part in new:
            r, t = ref[part], new[part]
            lines.append(
                f"| {part} | {t['n']} | {r['p50']:.2f} / {r['p95']:.2f} | "
                f"{t['p50']:.2f} / {t['p95']:.2f} | {r['p50'] / t['p50']:.2f}x | "
                f"{r['p95'] / t['p95']:.2f}x |"
            )
    if result["reference"].get("eval_episodes_per_minute"):
        r = float(np.median(result["reference"]["eval_episodes_per_minute"]))
        t = float(np.median(result["today"]["eval_episodes_per_minute"]))
        lines.append(f"| eval, episodes per minute (2 workers) | - | {r:.1f} | {t:.1f} | "
                     f"{t / r:.2f}x | - |")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", required=True, help="a commit, or a folder with src/")
    parser.add_argument("--checkpoint", type=Path, default=Path("checkpoints/vla_gr_cpu"))
    parser.add_argument(
        "--today-checkpoint", type=Path, default=None,
        help="today's code runs this one instead (e.g. with a latency-budget setting)",
    )  # fmt: skip
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--first", type=int, default=100)
    parser.add_argument("--split", default="val")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--eval-episodes", type=int, default=20, help="0: no eval timing")
    parser.add_argument("--worktrees", type=Path, default=Path(tempfile.gettempdir()))
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    sys.path.insert(0, str(REPO / "src"))
    from vla_gr.machine import describe_machine, machine_line

    codes = {"reference": source_tree(args.reference, args.worktrees), "today": REPO / "src"}
    checkpoints = {name: checkpoint_of(src, args.checkpoint) for name, src in codes.items()}
    if args.today_checkpoint is not None:
        checkpoints["today"] = args.today_checkpoint.resolve()
    runs: dict[str, dict] = {name: {"latency": [], "eval": [], "episodes": None} for name in codes}
    for repeat in range(args.repeats):
        order = list(codes) if repeat % 2 == 0 else list(reversed(codes))
        for name in order:
            logger.info("repeat %d: %s agent", repeat + 1, name)
            got = run_agent(codes[name], checkpoints[name], args)
            runs[name]["latency"].append(quantiles(got["samples"]))
            runs[name]["episodes"] = got["episodes"]
        for name in order if args.eval_episodes > 0 else ():
            logger.info("repeat %d: %s eval", repeat + 1, name)
            runs[name]["eval"].append(run_eval(codes[name], checkpoints[name], args))
    result = {
        name: {"latency": summarise(r["latency"]), "eval_episodes_per_minute": r["eval"],
               "success": float(np.mean([e["success"] for e in r["episodes"]]))}
        for name, r in runs.items()
    }  # fmt: skip
    result["decisions"] = decisions(runs["reference"]["episodes"], runs["today"]["episodes"])
    result["meta"] = {
        "reference": args.reference, "checkpoint": str(args.checkpoint),
        "today_checkpoint": None if args.today_checkpoint is None else str(args.today_checkpoint),
        "split": args.split,
        "first": args.first, "episodes": args.episodes, "repeats": args.repeats,
        "eval_episodes": args.eval_episodes, "machine": describe_machine(),
    }  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    d = result["decisions"]
    today = "" if args.today_checkpoint is None else f" --today-checkpoint {args.today_checkpoint}"
    text = (
        f"# Today's code against `{args.reference}`, side by side, one thread\n\n"
        f"`python benchmarks/bench_speed.py --reference {args.reference} --checkpoint "
        f"{args.checkpoint}{today} --episodes {args.episodes} --first {args.first} --split "
        f"{args.split} --repeats {args.repeats} --eval-episodes {args.eval_episodes}`\n\n"
        f"{machine_line(result['meta']['machine'])}\n\n{table(result)}\n\n"
        f"Success on the {args.episodes} episodes: reference {result['reference']['success']:.2f}, "
        f"today {result['today']['success']:.2f}; episodes with another outcome: "
        f"{d['episodes_with_other_outcome'] or 'none'}; largest action difference "
        f"{d['max_action_difference']:.2e}.\n"
    )
    args.out.with_suffix(".md").write_text(text)
    logger.info("\n%s", text)
    return result


if __name__ == "__main__":
    main()
