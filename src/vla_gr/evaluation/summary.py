"""``metrics.json`` from episode rows: means, breakdowns, failure causes, latency, parameters.

Everything except ``latency_ms`` and ``timing`` (wall-clock measurements) is a pure function
of the rows, so a resumed run writes the same ``metrics.json`` as an uninterrupted one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vla_gr.envs.metrics import aggregate
from vla_gr.evaluation.causes import CAUSES, REJECTED_GOAL_KINDS, WRONG_STOP_KINDS

BREAKDOWNS = ("num_rooms", "goal_category", "instruction_kind")
#: Keys of metrics.json that depend on wall-clock time (excluded from equality checks).
TIMING_KEYS = ("latency_ms", "timing")


def overall(rows: Sequence[dict]) -> dict:
    """Means over episodes of the final metrics, plus collision share and steps."""
    infos = [r["metrics"] for r in rows]
    out = aggregate(infos)
    out["collision_episode_share"] = float(np.mean([i["collisions"] > 0 for i in infos]))
    out["steps"] = float(np.mean([i["steps"] for i in infos]))
    return out


def breakdown(rows: Sequence[dict], key: str) -> dict[str, dict]:
    """{value of ``key``: {episodes, success, spl}} with values sorted."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(str(r[key]), []).append(r["metrics"])
    return {
        value: {
            "episodes": len(infos),
            "success": float(np.mean([i["success"] for i in infos])),
            "spl": float(np.mean([i["spl"] for i in infos])),
        }
        for value, infos in sorted(groups.items())
    }


def cause_counts(rows: Sequence[dict]) -> dict[str, int]:
    """Number of failed episodes per cause (every cause listed, zeros included)."""
    counts = dict.fromkeys(CAUSES, 0)
    for r in rows:
        if r["cause"] is not None:
            counts[r["cause"]] += 1
    return counts


def wrong_stop_counts(rows: Sequence[dict]) -> dict[str, int]:
    """Wrong STOPs per kind of object stopped next to (every kind listed, zeros included)."""
    counts = dict.fromkeys(WRONG_STOP_KINDS, 0)
    for r in rows:
        if r.get("wrong_stop") is not None:
            counts[r["wrong_stop"]] += 1
    return counts


def rejected_goal_counts(rows: Sequence[dict]) -> dict[str, dict[str, int]]:
    """Goals the agent rejected, {reason: {kind: count}} (every kind listed), plus
    ``episodes_failed_after_rejecting_the_goal``: failed episodes in which the goal instance
    itself was rejected at least once ({} when no row carries rejected goals)."""
    counts: dict[str, dict[str, int]] = {}
    failed_after = 0
    for r in rows:
        rejected = r.get("rejected_goals") or []
        for g in rejected:
            counts.setdefault(g["reason"], dict.fromkeys(REJECTED_GOAL_KINDS, 0))[g["kind"]] += 1
        if r["cause"] is not None and any(g["kind"] == "goal" for g in rejected):
            failed_after += 1
    if not counts:
        return {}
    key = "episodes_failed_after_rejecting_the_goal"
    return {**dict(sorted(counts.items())), key: failed_after}


def latency(rows: Sequence[dict]) -> dict[str, dict]:
    """Per part: p50/p95/p99/mean (ms) over every decision of every episode, and calls."""
    parts: dict[str, list[float]] = {}
    for r in rows:
        for part, values in r["latency_ms"].items():
            parts.setdefault(part, []).extend(values)
    out = {}
    for part, values in parts.items():
        v = np.asarray(values, dtype=np.float64)
        p50, p95, p99 = np.percentile(v, [50, 95, 99])
        out[part] = {
            "p50": float(p50),
            "p95": float(p95),
            "p99": float(p99),
            "mean": float(v.mean()),
            "calls": int(v.size),
        }
    return out


#: An episode whose planner never got this confident about any goal is flagged in the report.
LOW_GOAL_CONFIDENCE = 0.5


def low_confidence_episodes(rows: Sequence[dict]) -> list[int]:
    """Episode indices whose agent reported a goal confidence below ``LOW_GOAL_CONFIDENCE``
    (it never confirmed the instructed object: unknown words, an unseen goal)."""
    return [
        r["episode_index"]
        for r in rows
        if r.get("agent", {}).get("goal_confidence", 1.0) < LOW_GOAL_CONFIDENCE
    ]


#: Reworded instructions listed in ``metrics.json`` (every row keeps its own ``read_as``).
REWORDED_LISTED = 20


def reworded_instructions(rows: Sequence[dict]) -> dict:
    """Episodes whose instruction S2 read in other words (the agent's ``read_as``: the
    instruction lexicon's template phrasing): how many, their success rate, and the first
    ``REWORDED_LISTED`` as {episode, instruction, read_as}; {} when there are none."""
    reworded = [
        r for r in rows if r.get("agent", {}).get("read_as") not in (None, r["spec"]["instruction"])
    ]
    if not reworded:
        return {}
    return {
        "episodes": len(reworded),
        "success": float(np.mean([r["metrics"]["success"] for r in reworded])),
        "listed": [
            {
                "episode": r["episode_index"],
                "instruction": r["spec"]["instruction"],
                "read_as": r["agent"]["read_as"],
            }
            for r in reworded[:REWORDED_LISTED]
        ],
    }


def summarize_rows(
    rows: Sequence[dict],
    header: dict,
    seconds: float,
    workers: int,
    ran: int | None = None,
    machine: dict | None = None,
) -> dict:
    """The ``metrics.json`` content; ``header`` holds the run settings (agent, env, ...).

    ``seconds`` is the time this invocation took to run ``ran`` of the episodes (fewer than
    ``len(rows)`` after a resume), on ``machine`` (:func:`vla_gr.machine.describe_machine`).
    """
    ran = len(rows) if ran is None else ran
    if not rows:
        raise ValueError("no episodes to summarize")
    return {
        **header,
        "metrics": overall(rows),
        "breakdowns": {key: breakdown(rows, key) for key in BREAKDOWNS},
        "failure_causes": cause_counts(rows),
        "wrong_stops": wrong_stop_counts(rows),
        "rejected_goals": rejected_goal_counts(rows),
        "low_goal_confidence": low_confidence_episodes(rows),
        "reworded_instructions": reworded_instructions(rows),
        "parameters": rows[0]["parameters"],
        "latency_ms": latency(rows),
        "timing": {
            "seconds": seconds,
            "workers": workers,
            "episodes_run": ran,
            "episodes_per_min": 60.0 * ran / seconds if seconds > 0 and ran else 0.0,
            "machine": machine,
        },
    }


def without_timing(metrics: dict) -> dict:
    """``metrics`` minus its wall-clock entries (what two runs of the same eval share)."""
    return {k: v for k, v in metrics.items() if k not in TIMING_KEYS}
