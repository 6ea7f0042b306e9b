"""PEFT where it pays: the shipped agent adapted to the held-out house style ``loft`` with LoRA
and with full fine-tuning, measured closed loop on held-out episodes it was not adapted on.

    python benchmarks/bench_peft_adapt.py                       # the measurement
    python benchmarks/bench_peft_adapt.py --episodes 4 --steps 20 --collect 4 --rollouts 2 \
        --output /tmp/peft_smoke                                # a smoke run

1. Adaptation: the stages of ``recipe_adapt_loft`` (``vla-gr train --config-name
   recipe_adapt_loft``) under ``--output``/pipeline: expert episodes and DAgger rollouts of the
   shipped agent in ``loft`` houses on ``train`` episodes, then the ``lora`` (merged) and
   ``full`` adapt stages. A method's adaptation time is the data stages' plus its own stage's
   (their ``stage.json``); stages already done are skipped and keep their recorded times.
2. Evaluation: ``vla-gr eval ... env.house_style=loft workers=2`` on :data:`HELD_OUT` for the
   agent without adaptation, with LoRA and fully fine-tuned, and the shipped agent on the same
   episodes in the default style (the reference). An interrupted evaluation resumes.
3. ``benchmarks/results/bench_peft_adapt.{md,json}`` (a smoke run, on fewer episodes or at
   other sizes: ``bench_peft_adapt_smoke.*`` under ``--output``): SR, SPL, collision rate,
   the SR gain over no adaptation, trainable parameters and share, adaptation minutes, the
   goal head's held-out IoU on the adaptation frames before and after, and the
   merged-vs-unmerged check.

The held-out episodes were fixed here before anything was measured; ``--episodes`` only takes
the first of them.
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

#: The episodes the agents are measured on: (split, first, count), in the held-out style.
HELD_OUT = ("val", 200, 100)
STYLE = "loft"
RECIPE = "recipe_adapt_loft"
DATA_STAGES = ("expert", "rollouts", "dagger")  # shared by both methods
METHODS = {"lora": "LoRA r=8, merged", "full": "full fine-tuning"}
RESULTS = Path(__file__).resolve().parent / "results"


def adapt(args) -> dict[str, dict]:
    """Run (or resume) the recipe's stages; their records by name."""
    from vla_gr.configs import load_config
    from vla_gr.evaluation.harness import evaluate
    from vla_gr.train import train
    from vla_gr.training.pipeline import run_pipeline
    from vla_gr.training.stages import Services

    _, overrides = pipeline_overrides(args)
    resolved, cfg = load_config(RECIPE, overrides)
    return run_pipeline(resolved, cfg, Services(train=train, evaluate=evaluate))


def pipeline_overrides(args) -> tuple[str, list[str]]:
    """(the equivalent command, the recipe overrides) of this run's adaptation."""
    overrides = [
        f"pipeline.output_dir={Path(args.output) / 'pipeline'}",
        f"pipeline.stages.0.path={args.checkpoint}",  # the source stage: the agent adapted
        "collect.progress=false",
        "eval.progress=false",
        "logging.tensorboard=false",
    ]
    for key, value in (
        ("training.adapt.steps", args.steps),
        ("collect.num_episodes", args.collect),
        ("eval.num_episodes", args.rollouts),
    ):
        if value is not None:
            overrides.append(f"{key}={value}")
    return f"vla-gr train --config-name {RECIPE} " + " ".join(overrides), overrides


def evaluate_row(name: str, checkpoint: str, style: str, args) -> tuple[str, dict]:
    """(the equivalent command, metrics.json) of one agent on the held-out episodes."""
    from vla_gr.configs import load_config
    from vla_gr.evaluate import evaluate, expand_aliases

    split, first, _ = HELD_OUT
    overrides = [
        f"checkpoint={checkpoint}",
        f"split={split}",
        f"first_episode={first}",
        f"num_episodes={args.episodes}",
        f"env.house_style={style}",
        f"workers={args.workers}",
        f"output_dir={Path(args.output) / 'eval' / name}",
        "eval.video_successes=0",
        "eval.video_per_cause=0",
        "eval.progress=false",
    ]
    _, cfg = load_config("config_cpu", expand_aliases(overrides))
    return "vla-gr eval " + " ".join(overrides), evaluate(cfg)


def adaptation_rows(records: dict[str, dict]) -> dict[str, dict]:
    """Per method: its agent, minutes (data stages + its stage) and the summary it recorded."""
    from vla_gr.checkpoint import read_checkpoint

    data = sum(records[s]["seconds"] for s in DATA_STAGES)
    rows = {}
    for method in METHODS:
        agent = records[method]["product"]
        summary = read_checkpoint(agent).state["goal_head_adaptation"]
        rows[method] = {
            "checkpoint": agent,
            "data_minutes": round(data / 60, 2),
            "stage_minutes": round(records[method]["seconds"] / 60, 2),
            "adapt_minutes": round((data + records[method]["seconds"]) / 60, 2),
            "summary": summary,
        }
    return rows


def metric_row(metrics: dict) -> dict:
    m = metrics["metrics"]
    return {
        "SR": m["success"],
        "SPL": m["spl"],
        "collision_rate": m["collision_rate"],
        "episodes": m["episodes"],
        "failure_causes": metrics.get("failure_causes"),
    }


def table(rows: dict[str, dict], adapted: dict[str, dict], commands: dict, args, wall) -> str:
    from vla_gr.machine import describe_machine, machine_line

    split, first, _ = HELD_OUT
    base = rows["none"]["SR"]
    lines = [
        f"# PEFT where it pays: the shipped goal head adapted to the `{STYLE}` house style",
        "",
        f"Held out: `{split}` {first}-{first + args.episodes - 1} ({args.episodes} episodes), "
        f"fixed before any measurement; adapted on `train` episodes only ({RECIPE}).",
        "",
        f"`{commands['bench']}`",
        "",
        "| agent | style | SR | SPL | collision rate | SR gain vs none | trainable parameters "
        "| share of goal head | share of agent | adaptation min | held-out goal IoU |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    names = {"shipped_default": "shipped (reference)", "none": "no adaptation", **METHODS}
    for key, r in rows.items():
        a = adapted.get(key)
        style = "default" if key == "shipped_default" else STYLE
        cells = ["", "", "", "", ""]
        if a is not None:
            s = a["summary"]
            iou = f"{s['held_out_before']['goal_iou']:.3f} -> {s['held_out_after']['goal_iou']:.3f}"
            cells = [
                f"{s['trainable_parameters']:,}",
                f"{s['share_of_goal_head']:.2%}",
                f"{s['share_of_agent']:.2%}",
                f"{a['adapt_minutes']:.1f}",
                iou,
            ]
        gain = "" if key == "shipped_default" else f"{r['SR'] - base:+.3f}"
        lines.append(
            f"| {names[key]} | {style} | {r['SR']:.3f} | {r['SPL']:.3f} | "
            f"{r['collision_rate']:.3f} | {gain} | " + " | ".join(cells) + " |"
        )
    lora = adapted["lora"]["summary"]
    lines += [
        "",
        f"Adaptation minutes: the shared data stages ({adapted['lora']['data_minutes']:.1f} min: "
        f"{', '.join(DATA_STAGES)}) plus the method's stage (LoRA "
        f"{adapted['lora']['stage_minutes']:.1f}, full {adapted['full']['stage_minutes']:.1f}); "
        f"{lora['steps']} steps of {lora['batch_size']} frames each "
        f"({lora['train_windows']} training windows). Merged LoRA vs unmerged on held-out "
        f"frames: max |logit difference| {lora['merge_max_abs_diff']:.1e}. Held-out goal IoU: "
        "the adaptation store's held-out episodes, before -> after.",
        "",
        f"Adaptation: `{commands['adapt']}`. Evaluations: "
        + "; ".join(f"`{c}`" for c in commands["rows"].values()),
        "",
        f"{machine_line(describe_machine())} Wall {wall / 60:.1f} min.",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument("--episodes", type=int, default=HELD_OUT[2],
                        help=f"the first N of the {HELD_OUT[2]} held-out episodes")  # fmt: skip
    parser.add_argument("--steps", type=int, help="training.adapt.steps (default: the recipe's)")
    parser.add_argument("--collect", type=int, help="expert episodes (default: the recipe's)")
    parser.add_argument("--rollouts", type=int, help="DAgger rollouts (default: the recipe's)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--output", default="outputs/bench_peft_adapt")
    args = parser.parse_args()
    if not 1 <= args.episodes <= HELD_OUT[2]:
        parser.error(f"--episodes={args.episodes} must be in [1, {HELD_OUT[2]}]")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    t0 = time.perf_counter()
    records = adapt(args)
    adapted = adaptation_rows(records)
    commands = {"adapt": pipeline_overrides(args)[0], "rows": {}}
    rows = {}
    for key, checkpoint, style in (
        ("shipped_default", args.checkpoint, "default"),
        ("none", args.checkpoint, STYLE),
        ("lora", adapted["lora"]["checkpoint"], STYLE),
        ("full", adapted["full"]["checkpoint"], STYLE),
    ):
        commands["rows"][key], metrics = evaluate_row(key, checkpoint, style, args)
        rows[key] = metric_row(metrics)
        print(f"{key}: SR {rows[key]['SR']:.3f} SPL {rows[key]['SPL']:.3f}", flush=True)
    smoke = args.episodes < HELD_OUT[2] or any(
        v is not None for v in (args.steps, args.collect, args.rollouts)
    )
    flags = [f"--{k} {v}" for k, v in vars(args).items() if v is not None and k != "output"]
    commands["bench"] = "python benchmarks/bench_peft_adapt.py " + " ".join(flags)
    text = table(rows, adapted, commands, args, time.perf_counter() - t0)
    print(text)
    stem = Path(args.output) / "bench_peft_adapt_smoke" if smoke else RESULTS / "bench_peft_adapt"
    stem.parent.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".md").write_text(text + "\n")
    record = {
        "held_out": {"split": HELD_OUT[0], "first": HELD_OUT[1], "episodes": args.episodes},
        "style": STYLE,
        "commands": commands,
        "rows": rows,
        "adaptation": adapted,
        "wall_minutes": round((time.perf_counter() - t0) / 60, 2),
    }
    stem.with_suffix(".json").write_text(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
