"""``vla-gr demo`` (``make demo``): the shipped agent on ``val`` episodes, its table and report.

Runs :func:`vla_gr.evaluate.evaluate` with ``demo.*`` in place of ``eval.*``: by default the
agent checkpoint shipped in the repository (``checkpoints/vla_gr_cpu``, trained with
``config_cpu`` on a 2-core CPU) on 20 ``val`` episodes (houses it never saw) in two worker
processes. ``demo.output_dir`` (default ``outputs/demo``) gets the evaluation's run folder:
``metrics.json``, ``episodes.jsonl``, ``report.md`` with bar charts, top-down trajectories
and RGB | depth | map GIFs. The table is printed to stdout.

``vla-gr demo demo.train=true`` is the whole pipeline from an empty folder: collect the
expert data if missing, train the recipe's agent; for a dual system, run the S1 stage
(``training.s1``: rollouts, teacher relabelling, S1 training; :mod:`vla_gr.training.s1_stage`);
then evaluate the result.
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
    from vla_gr.evaluate import evaluate
    from vla_gr.evaluation.report import table_row

    d = cfg.demo
    checkpoint = d.checkpoint
    if d.train:
        from vla_gr.train import train

        summary = train(cfg, resolved)
        checkpoint = str(Path(summary["run_dir"]) / "checkpoints" / "best")
        if cfg.model.agent == "dual_system" and cfg.training.s1.enabled:
            from vla_gr.training.s1_stage import run_s1_stage

            stage_dir = Path(summary["run_dir"]) / "s1_stage"
            checkpoint = str(run_s1_stage(cfg, checkpoint, stage_dir))
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
    sys.stdout.write(f"report: {out_dir / 'report.md'}\n")
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
