"""Helpers of ``vla-gr eval`` (the app is :mod:`vla_gr.evaluate`).

- :mod:`.agents`  name -> factory registry (``checkpoint``, ``true_mask``, ``true_category``,
  ``expert``, ``random``) and the variants of ``eval.variants`` built on it;
- :mod:`.runner`  the episode loop with its per-step record, spawn workers, JSONL rows;
- :mod:`.ray_rows` the same workers as Ray actors on a cluster (``eval.backend=ray``);
- :mod:`.causes`  failure causes from an episode's record;
- :mod:`.summary` ``metrics.json`` from rows (means, breakdowns, causes, latency);
- :mod:`.report`  ``report.md``, bar charts, replayed GIFs and top-down pictures.
"""

from vla_gr.evaluation.agents import AGENTS, make_agent, register_agent
from vla_gr.evaluation.causes import CAUSES, CauseThresholds, failure_cause

__all__ = [
    "AGENTS",
    "CAUSES",
    "CauseThresholds",
    "failure_cause",
    "make_agent",
    "register_agent",
]
