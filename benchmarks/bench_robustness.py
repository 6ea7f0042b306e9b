"""Robustness of an agent: the same episodes clean, paraphrased, with depth and actuation noise.

    python benchmarks/bench_robustness.py --checkpoint checkpoints/vla_gr_cpu \
        --split test --episodes 200 --workers 2

Runs ``vla-gr eval`` (the ``config_cpu`` recipe) once per condition on episodes
``first .. first + episodes - 1`` of the split:

- ``clean``: as they are;
- ``paraphrase``: the same episodes with instructions rewritten by
  :func:`vla_gr.envs.paraphrase.paraphrase_episodes` (synonyms and sentence shapes the
  templates never use): in the held-out vocabulary, or with ``--vocabulary validation`` in
  the one for choosing settings, or ``second_held_out`` / ``third_held_out`` (the results
  file gets a ``_<vocabulary>`` suffix for any but ``held_out``);
- ``depth_noise``: ``env.depth_noise_std=0.02`` (Gaussian, metres, per pixel);
- ``actuation_noise``: ``env.actuation_noise=0.1`` (+-10% on v and w, per step).

Prints SR / SPL / collision rate per condition and the SR difference to ``clean``, writes
``benchmarks/results/bench_robustness_<name>_<split>.{json,md}`` (``--name``, default the agent:
give each checkpoint its own; conditions run earlier on the same agent and episodes are kept,
so ``--conditions`` may be run one at a time); each run
folder is kept under ``--output`` (default ``outputs/robustness``).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
os.environ.setdefault("HF_HUB_OFFLINE", "1")

CONDITIONS = {
    "clean": [],
    "paraphrase": [],  # episodes file written below
    "depth_noise": ["env.depth_noise_std=0.02"],
    "actuation_noise": ["env.actuation_noise=0.1"],
}
RESULTS = Path(__file__).resolve().parent / "results"


def run_condition(name: str, args, episodes_file: Path | None) -> dict:
    """Evaluate one condition; its metrics.json."""
    from vla_gr.configs import load_config
    from vla_gr.evaluate import evaluate, expand_aliases

    other = name == "paraphrase" and args.vocabulary != "held_out"
    out = Path(args.output) / (f"{args.split}-{name}" + (f"-{args.vocabulary}" if other else ""))
    overrides = [
        f"agent={args.agent}",
        f"workers={args.workers}",
        f"output_dir={out}",
        "eval.video_successes=0",
        "eval.video_per_cause=0",
        "eval.progress=false",
        *CONDITIONS[name],
    ]
    if args.agent == "checkpoint":
        overrides.append(f"checkpoint={args.checkpoint}")
    if episodes_file is None:
        overrides += [f"split={args.split}", f"first_episode={args.first}"]
        overrides.append(f"num_episodes={args.episodes}")
    else:
        overrides.append(f"episodes={episodes_file}")
    _, cfg = load_config("config_cpu", expand_aliases(overrides))
    return evaluate(cfg)


def paraphrased_episodes(args) -> Path:
    """Write the split's episodes with paraphrased instructions; the file's path."""
    from vla_gr.envs.episodes import sample_episode, save_episodes
    from vla_gr.envs.paraphrase import VOCABULARIES, paraphrase_episodes

    specs = [sample_episode(args.split, k) for k in range(args.first, args.first + args.episodes)]
    vocabulary = VOCABULARIES[args.vocabulary]
    path = Path(args.output) / f"{args.split}-paraphrased-{args.vocabulary}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_episodes(path, paraphrase_episodes(specs, seed=0, vocabulary=vocabulary))


def main() -> None:
    from vla_gr.machine import describe_machine, machine_line

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument("--agent", default="checkpoint")
    parser.add_argument("--split", default="test")
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--conditions", default=",".join(CONDITIONS))
    parser.add_argument("--output", default="outputs/robustness")
    parser.add_argument(
        "--name", help="the results file's agent part (default: --agent); one per checkpoint"
    )
    from vla_gr.envs.paraphrase import VOCABULARIES

    parser.add_argument(
        "--vocabulary", choices=[v for v in VOCABULARIES if v != "training"],
        default="held_out",
        help="the paraphrases' vocabulary: held_out reports, validation chooses settings, "
        "second_held_out ... sixth_held_out measure a change designed on an earlier set's failures",
    )  # fmt: skip
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    rows, t0 = {}, time.perf_counter()
    for name in args.conditions.split(","):
        if name not in CONDITIONS:
            parser.error(f"unknown condition {name!r}; choose from {list(CONDITIONS)}")
        episodes = paraphrased_episodes(args) if name == "paraphrase" else None
        m = run_condition(name, args, episodes)
        rows[name] = {
            "SR": m["metrics"]["success"],
            "SPL": m["metrics"]["spl"],
            "collision_rate": m["metrics"]["collision_rate"],
            "episodes": m["metrics"]["episodes"],
            "failure_causes": m["failure_causes"],
        }
        print(f"{name}: SR {rows[name]['SR']:.3f} SPL {rows[name]['SPL']:.3f}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    suffix = "" if args.vocabulary == "held_out" else f"_{args.vocabulary}"
    stem = RESULTS / f"bench_robustness_{args.name or args.agent}_{args.split}{suffix}"
    key = [args.agent, args.checkpoint, args.split, args.first, args.episodes]
    if stem.with_suffix(".json").is_file():  # conditions of an earlier run on the same episodes
        old = json.loads(stem.with_suffix(".json").read_text())
        if old.get("key") == key:
            rows = {**old["rows"], **rows}
    rows = {name: rows[name] for name in CONDITIONS if name in rows}
    base = rows.get("clean", {}).get("SR")
    command = (
        f"python benchmarks/bench_robustness.py --agent {args.agent} --checkpoint "
        f"{args.checkpoint} --split {args.split} --first {args.first} --episodes "
        f"{args.episodes} --workers {args.workers}"
        + (f" --name {args.name}" if args.name else "")
        + (f" --vocabulary {args.vocabulary}" if suffix else "")
    )
    lines = [
        f"# Robustness: {args.agent} on {args.split} {args.first}-{args.first + args.episodes - 1}",
        "",
        f"`{command}`",
        "",
        "| condition | episodes | SR | SPL | collision rate | SR - clean SR |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        delta = "" if base is None else f"{r['SR'] - base:+.3f}"
        lines.append(
            f"| {name} | {r['episodes']} | {r['SR']:.3f} | {r['SPL']:.3f} | "
            f"{r['collision_rate']:.3f} | {delta} |"
        )
    lines += ["", f"{machine_line(describe_machine())} Wall {time.perf_counter() - t0:.0f} s."]
    table = "\n".join(lines)
    print(table)
    stem.with_suffix(".md").write_text(table + "\n")
    record = {"key": key, "command": command, "rows": rows}
    stem.with_suffix(".json").write_text(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
