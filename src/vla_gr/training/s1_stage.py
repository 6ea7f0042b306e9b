"""The S1 stage of a dual-system agent: rollouts -> teacher relabelling -> S1 training.

After ``vla-gr train`` has trained S2's goal head (S1 drives by pure pursuit meanwhile), the
stage rolls that agent out on ``training.s1.episodes`` ``train`` episodes with ``vla-gr
eval``, relabels every visited state with the local teacher (:mod:`.s1_data`) and trains the
learned S1 on them (:mod:`.s1`). The result is the agent with ``model.s1.kind=learned``.
``vla-gr demo demo.train=true`` runs it after training; by hand:

    python -m vla_gr.training.s1_stage outputs/train/<run>/checkpoints/best outputs/s1_stage
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from vla_gr.training.command import run_command

log = logging.getLogger(__name__)

__all__ = ["run_s1_stage"]


def run_s1_stage(cfg, checkpoint: str | Path, work_dir: str | Path) -> Path:
    """Run the stage for a validated ``VLAGRConfig``; returns the agent's checkpoint folder
    (``<work_dir>/agent``). ``work_dir`` also gets ``rollouts/`` and ``data/``."""
    from vla_gr.evaluate import evaluate
    from vla_gr.training.s1 import train_s1
    from vla_gr.training.s1_data import relabel_run

    stage = cfg.training.s1
    work = Path(work_dir)
    rollouts, data, agent = work / "rollouts", work / "data", work / "agent"
    eval_cfg = dataclasses.replace(
        cfg.eval,
        agent="checkpoint",
        agents=[],
        checkpoint=str(checkpoint),
        model_overrides=["s1.kind=pure_pursuit"],
        split="train",
        episodes=None,
        num_episodes=stage.episodes,
        first_episode=stage.first_episode,
        workers=stage.workers,
        output_dir=str(rollouts),
        gif_successes=0,
        gif_per_cause=0,
    )
    metrics = evaluate(dataclasses.replace(cfg, eval=eval_cfg))
    log.info("S1 stage rollouts: SR %.3f on %d train episodes", metrics["metrics"]["success"],
             stage.episodes)  # fmt: skip
    if not (data / "manifest.json").exists():
        relabel_run(rollouts, checkpoint, data, workers=stage.workers)
    train_s1(
        checkpoint, agent, [data], steps=stage.steps, batch_size=stage.batch_size,
        lr=stage.lr, seed=cfg.seed, settings=stage.settings,
    )  # fmt: skip
    return agent


def main(argv: Sequence[str] | None = None) -> int:
    from vla_gr.configs import load_config

    parser = argparse.ArgumentParser(prog="python -m vla_gr.training.s1_stage")
    parser.add_argument("checkpoint", help="the dual-system agent whose goal head is trained")
    parser.add_argument("work_dir", help="rollouts/, data/ and agent/ go here")
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. training.s1.steps=500")
    parser.add_argument("--config-name", default="config_cpu")

    def work(args: argparse.Namespace) -> None:
        _, cfg = load_config(args.config_name, args.overrides)
        sys.stdout.write(f"{run_s1_stage(cfg, args.checkpoint, args.work_dir)}\n")

    return run_command(parser, argv, work, limit_threads=False)


if __name__ == "__main__":
    sys.exit(main())
