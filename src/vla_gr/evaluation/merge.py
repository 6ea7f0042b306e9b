"""Eval runs of disjoint shares of one config's episodes, written as the one run they make up.

Under torchrun a recipe's rollout stage runs once, split across the ranks: each rank evaluates
its share of ``eval``'s episodes into a folder of its own (:func:`.harness.evaluate`), then rank
0 calls :func:`merge_runs`, which writes what a single process would have: ``run.json`` of the
whole range, ``episodes.jsonl`` in episode order, ``metrics.json`` and the report. The train app
hands it to the pipeline (:class:`~vla_gr.training.stages.Services`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

__all__ = ["merge_runs"]


def merge_runs(cfg, parts: Sequence[str | Path], agent: str | None = None) -> dict:
    """Write the rows of eval run folders ``parts`` (shares of ``cfg``'s episodes, run with
    the same agent and settings) into ``cfg.eval.output_dir`` as one run; returns its
    metrics.json.

    The harness then resumes every row and only summarises: an index that no share wrote (a
    house that hosts no episode) is tried there once more. A row found in two shares, or
    outside ``cfg``'s episodes, is refused (``EvalInputError`` naming the episode).
    """
    from vla_gr.evaluation.harness import (
        EvalInputError,
        default_agent,
        evaluate,
        plan_episodes,
        run_header,
    )
    from vla_gr.evaluation.runner import RowWriter, read_rows

    agent = agent or default_agent(cfg)
    indices, _, source = plan_episodes(cfg)
    wanted = set(indices)
    rows: dict[int, dict] = {}
    for part in map(Path, parts):
        for row in read_rows(part / "episodes.jsonl"):
            k = row["episode_index"]
            if k not in wanted or k in rows:
                why = "is in two shares" if k in rows else f"is not one of {source}'s episodes"
                raise EvalInputError(f"episode {k} of {part} {why} (eval.first_episode, "
                                     "eval.num_episodes)")  # fmt: skip
            rows[k] = row
    out = Path(cfg.eval.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    header = run_header(cfg, agent, source, indices)
    (out / "run.json").write_text(json.dumps(header, indent=1))
    RowWriter(out / "episodes.jsonl", [rows[k] for k in indices if k in rows]).close()
    return evaluate(cfg, agent)
