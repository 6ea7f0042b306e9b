"""``vla-gr demo`` (``make demo``): the shipped agent on ``val`` episodes, its table and report.

Runs :func:`vla_gr.evaluation.harness.evaluate` with ``demo.*`` in place of ``eval.*``: by
default the agent checkpoint shipped in the repository (``checkpoints/vla_gr_cpu``, trained with
``config_cpu`` on a 2-core CPU) on 20 ``val`` episodes (houses it never saw) in two worker
processes. ``demo.output_dir`` (default ``outputs/demo``) gets the evaluation's run folder:
``metrics.json``, ``episodes.jsonl``, ``report.md`` / ``report.html`` with bar charts,
top-down trajectories and RGB | depth | map videos. The table is printed to stdout.

``vla-gr demo demo.train=true`` first runs the recipe's stages (``pipeline.stages``, as
``vla-gr train`` does; ``config_cpu``: expert data, goal head, rollouts, S1 data, learned S1)
and evaluates the last stage's agent.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from vla_gr.errors import UserError

log = logging.getLogger(__name__)

__all__ = ["run_demo", "run_from_cli"]


def _fresh_output_dir(path: Path) -> None:
    """Empty a previous demo's folder (only if it holds an evaluation run) so it reruns."""
    if not path.exists():
        return
    if not (path / "run.json").is_file():
        raise UserError(f"demo.output_dir={path} exists and is not a demo run folder")
    shutil.rmtree(path)


def run_demo(cfg, resolved=None) -> dict:
    """Run the demo for a validated ``VLAGRConfig``; returns the evaluation's metrics."""
    from vla_gr.envs.metrics import format_table
    from vla_gr.evaluation.harness import evaluate
    from vla_gr.evaluation.report import table_row

    d = cfg.demo
    checkpoint = d.checkpoint
    if d.train:  # the recipe's stages (as `vla-gr train` runs them); its last product drives
        from omegaconf import OmegaConf

        from vla_gr.train import train
        from vla_gr.training.pipeline import run_pipeline
        from vla_gr.training.stages import Services

        if not cfg.pipeline.stages:
            raise UserError("demo.train=true runs the recipe's pipeline.stages; it has none")
        resolved = resolved if resolved is not None else OmegaConf.structured(cfg)
        records = run_pipeline(resolved, cfg, Services(train=train, evaluate=evaluate))
        checkpoint = list(records.values())[-1]["product"]
    out_dir = Path(d.output_dir)
    _fresh_output_dir(out_dir)
    eval_cfg = dataclasses.replace(
        cfg.eval,
        agent=d.agent,
        checkpoint=checkpoint if d.agent == "checkpoint" else None,
        split=d.split,
        episodes=None,
        num_episodes=d.num_episodes,
        first_episode=d.first_episode,
        workers=d.workers,
        output_dir=str(out_dir),
    )
    metrics = evaluate(dataclasses.replace(cfg, eval=eval_cfg))
    table = format_table({metrics["agent"]: table_row(metrics)})
    sys.stdout.write(table + "\n")
    causes = {k: v for k, v in metrics["failure_causes"].items() if v}
    sys.stdout.write(f"failure causes: {json.dumps(causes)}\n")
    sys.stdout.write(f"report: {out_dir / 'report.html'} (and report.md)\n")
    sys.stdout.flush()
    return metrics


def run_from_cli(config_name: str, overrides: Sequence[str]) -> int:
    """``vla-gr demo [--config-name NAME] [key=value ...]``; returns the exit code."""
    from vla_gr.configs import load_config

    resolved, cfg = load_config(config_name, overrides)
    run_demo(cfg, resolved)
    return 0


if __name__ == "__main__":
    from vla_gr.configs.command import module_main

    sys.exit(module_main("demo", run_from_cli))
