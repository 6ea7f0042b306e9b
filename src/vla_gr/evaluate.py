"""``vla-gr eval``: closed-loop evaluation of any agent on any episodes.

``vla-gr eval [--config-name NAME] agent=<name> [checkpoint=<run>/checkpoints/best]
split=val num_episodes=N | episodes=<file.jsonl> workers=W seed=S [output_dir=DIR]``
(the bare keys are short for ``eval.<key>``). Given no ``agent``, ``agents`` or ``checkpoint``
(on the command line or in the recipe) it runs the shipped agent
(``agent=checkpoint checkpoint=checkpoints/vla_gr_cpu``) and its first line says so; the
geodesic expert, which reads the world's privileged state, runs only when named
(``agent=expert``).
Writes to ``output_dir`` (default
``outputs/eval/<agent>-<split>-<timestamp>``): ``episodes.jsonl`` (one row per episode,
flushed as each finishes), ``metrics.json``, ``report.md`` with bar charts, top-down PNGs
and episode videos, ``report.html`` (the same, with players). Run again with the same
``output_dir`` after a kill and it resumes: finished rows are read back, the rest run, and
``metrics.json`` equals an uninterrupted run's.
``--config-name compare agents=[a,b]`` runs several agents on the same episodes and
writes ``compare.md`` / ``compare.json``. After the table it prints, for an agent that reads
requests, how many it did not fully understand, and for absent-object episodes (an episodes
file with ``absent`` specs, ``benchmarks/absent_episodes.py``) how they ended. ``--cfg job``
prints the config it would run with (:func:`compose_from_cli`).

``rollout_policy`` / ``summarize`` (from :mod:`vla_gr.evaluation.runner`, re-exported) are
the library calls training's closed-loop validation uses: the same episode loop.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from vla_gr.configs.keys import EVAL_ALIASES
from vla_gr.configs.schema import SHIPPED_CHECKPOINT
from vla_gr.errors import UserError
from vla_gr.evaluation.harness import (
    DEFAULT_SPLIT_EPISODES,
    EvalInputError,
    compare,
    evaluate,
    plan_episodes,
)
from vla_gr.evaluation.runner import rollout_policy, summarize

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_SPLIT_EPISODES",
    "EVAL_ALIASES",
    "EvalInputError",
    "compare",
    "compose_from_cli",
    "evaluate",
    "expand_aliases",
    "plan_episodes",
    "rollout_policy",
    "run_from_cli",
    "shipped_agent_default",
    "summarize",
]


def expand_aliases(overrides: Sequence[str]) -> list[str]:
    """``agent=x`` -> ``eval.agent=x`` for the keys of ``EVAL_ALIASES``; others unchanged."""
    out = []
    for item in overrides:
        key = item.split("=", 1)[0]
        out.append(f"eval.{item}" if key in EVAL_ALIASES else item)
    return out


def shipped_agent_default(eval_cfg) -> dict[str, str]:
    """The ``eval.*`` values that name the agent when ``eval_cfg`` names none (no ``agent``,
    ``agents`` or ``checkpoint``): the shipped checkpoint; {} when it names one."""
    if eval_cfg.agent or eval_cfg.agents or eval_cfg.checkpoint:
        return {}
    return {"agent": "checkpoint", "checkpoint": SHIPPED_CHECKPOINT}


def _compose(config_name: str, overrides: Sequence[str]):
    """(resolved DictConfig, VLAGRConfig, whether the shipped agent was filled in)."""
    import dataclasses

    from vla_gr.configs import load_config

    resolved, cfg = load_config(config_name, expand_aliases(overrides))
    default = shipped_agent_default(cfg.eval)
    if default:
        for key, value in default.items():
            resolved.eval[key] = value
        cfg = dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, **default))
    return resolved, cfg, bool(default)


def compose_from_cli(config_name: str, overrides: Sequence[str]):
    """The config ``vla-gr eval`` runs with: recipe ``config_name`` with ``overrides`` (bare
    keys of :data:`EVAL_ALIASES` meaning ``eval.<key>``) and, when it names no agent, the
    shipped one (:func:`shipped_agent_default`). Returns (resolved DictConfig, VLAGRConfig)."""
    resolved, cfg, _ = _compose(config_name, overrides)
    return resolved, cfg


def run_from_cli(config_name: str, overrides: Sequence[str]) -> int:
    """``vla-gr eval [--config-name NAME] [key=value ...]``; returns the exit code."""
    from pathlib import Path

    from vla_gr.envs.metrics import format_table
    from vla_gr.evaluation.report import table_row

    _, cfg, shipped = _compose(config_name, overrides)
    if cfg.env.episodes and cfg.env.episodes != cfg.eval.episodes:  # else the split would run
        raise UserError(
            f"env.episodes={cfg.env.episodes}: vla-gr eval runs the episodes file of "
            f"eval.episodes; pass episodes={cfg.env.episodes}"
        )
    if shipped:
        sys.stdout.write(
            f"agent: the shipped checkpoint {SHIPPED_CHECKPOINT} (no agent= or checkpoint= "
            "given; agent=expert runs the privileged expert)\n"
        )
        sys.stdout.flush()
        if not Path(SHIPPED_CHECKPOINT).is_dir():
            raise UserError(
                f"the shipped checkpoint {SHIPPED_CHECKPOINT} is not in {Path.cwd()}: run from "
                "the repository's root, or name the agent (checkpoint=PATH, agent=NAME)"
            )
    if cfg.eval.agents:
        result = compare(cfg)
        lines = [result["table"]]
        for agent, metrics in result["metrics"].items():
            lines += [f"{agent}: {line}" for line in understood_lines(metrics)]
            lines += [f"{agent}: {line}" for line in absent_summary(metrics)]
    else:
        metrics = evaluate(cfg)
        lines = [format_table({metrics["agent"]: table_row(metrics)}), *understood_lines(metrics)]
        lines += absent_summary(metrics)
    sys.stdout.write("\n".join(lines) + "\n")
    sys.stdout.flush()
    return 0


def understood_lines(metrics: dict) -> list[str]:
    """``["N of M requests were not fully understood"]`` when the agent read any request
    (``metrics.json``'s ``not_understood`` and ``requests_read``), else []."""
    read = metrics.get("requests_read", 0)
    if not read:
        return []
    return [f"{metrics['not_understood']} of {read} requests were not fully understood"]


def absent_summary(metrics: dict) -> list[str]:
    """One line on the absent-object episodes (``metrics.json``'s ``absent_objects``): how
    many the agent declared not found, ended with a false STOP or ran out of steps on, and the
    median steps to declare; [] without any."""
    a = metrics.get("absent_objects") or {}
    if not a.get("episodes"):
        return []
    spread = a["steps_to_declare"]
    median = "-" if spread is None else f"{spread['median']:.0f}"
    return [
        f"absent objects ({a['episodes']} episodes, not in SR / SPL): declared not found "
        f"{a['declared_not_found']}, false STOPs {a['false_stops']}, timeouts {a['timeouts']}, "
        f"median steps to declare {median}"
    ]


if __name__ == "__main__":
    from vla_gr.configs.command import module_main

    sys.exit(module_main("evaluate", run_from_cli, compose=compose_from_cli))
