"""``metrics.json`` from episode rows: means, breakdowns, failure causes, declared outcomes,
requests not understood, absent objects, latency, parameters.

Absent-object episodes (rows with ``absent``: the request names an object the house does not
have) never enter SR / SPL, the breakdowns, the failure causes or the declared outcomes: those
are the normal episodes', where declaring ``not_found`` is a failure (cause ``not_found``).
:func:`absent_objects` counts them apart: right declarations, false STOPs, timeouts, and the
steps it took to declare.

Everything except ``latency_ms`` and ``timing`` (wall-clock measurements) is a pure function
of the rows, so a resumed run writes the same ``metrics.json`` as an uninterrupted one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vla_gr.envs import DECLARED_OUTCOMES
from vla_gr.envs.metrics import aggregate
from vla_gr.evaluation.causes import CAUSES, REJECTED_GOAL_KINDS, WRONG_STOP_KINDS

BREAKDOWNS = ("num_rooms", "goal_category", "instruction_kind")
#: Keys of metrics.json that depend on wall-clock time (excluded from equality checks).
TIMING_KEYS = ("latency_ms", "timing")


def overall(rows: Sequence[dict]) -> dict:
    """Means over episodes of the final metrics, plus collision share and steps
    (``{"episodes": 0}`` for no rows)."""
    if not rows:
        return {"episodes": 0}
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


def declared_counts(rows: Sequence[dict]) -> dict[str, int]:
    """Episodes ended by each declared outcome (every outcome listed, zeros included; rows of
    older runs have no ``declared``)."""
    counts = dict.fromkeys(DECLARED_OUTCOMES, 0)
    for r in rows:
        if r.get("declared") is not None:
            counts[r["declared"]] += 1
    return counts


def is_absent(row: dict) -> bool:
    """Whether ``row`` is an absent-object episode's (rows of older runs never are)."""
    return bool(row.get("absent", False))


def _share(count: int, total: int) -> float | None:
    return count / total if total else None


def absent_objects(rows: Sequence[dict]) -> dict:
    """The absent-object episodes of ``rows``: how many, how many the agent declared
    ``not_found`` (the right outcome), ended with a STOP (false STOPs, by
    :func:`~vla_gr.evaluation.causes.wrong_stop_kind`), ran out of steps (``timeouts``) or
    declared ``not_understood``; their shares, and the steps to declare not found (median,
    mean, max; None without a declaration)."""
    absent = [r for r in rows if is_absent(r)]
    n = len(absent)
    declared = [r["metrics"]["steps"] for r in absent if r.get("declared") == "not_found"]
    stops = sum(bool(r["stopped"]) for r in absent)
    timeouts = sum(not r["stopped"] and r.get("declared") is None for r in absent)
    steps = np.asarray(declared, dtype=np.float64)
    spread = None
    if declared:
        spread = {"median": float(np.median(steps)), "mean": float(steps.mean()),
                  "max": float(steps.max())}  # fmt: skip
    return {
        "episodes": n,
        "declared_not_found": len(declared),
        "false_stops": stops,
        "timeouts": timeouts,
        "not_understood": sum(r.get("declared") == "not_understood" for r in absent),
        "declared_not_found_rate": _share(len(declared), n),
        "false_stop_rate": _share(stops, n),
        "steps_to_declare": spread,
        "false_stops_by_kind": wrong_stop_counts(absent),
    }


def readings(rows: Sequence[dict]) -> list[dict]:
    """The rows whose agent read the request (a ``reading`` that is not None)."""
    return [r for r in rows if r.get("reading") is not None]


def not_understood_count(rows: Sequence[dict]) -> int:
    """Rows whose reading says the request was not understood."""
    return sum(not r["reading"]["understood"] for r in readings(rows))


#: Readings that differ from their episode's description, listed in the report.
MISMATCHES_LISTED = 20
#: A reading's fields and the keys of an episode's description they are compared with.
COMPARED_FIELDS = (("category", "category"), ("color", "color"), ("room", "room"),
                   ("anchor", "near"))  # fmt: skip


def fields_text(fields: dict) -> str:
    """'category=chair color=red' for the named reading fields ('nothing' when none is)."""
    named = [f"{k}={fields[k]}" for k, _ in COMPARED_FIELDS if fields.get(k) is not None]
    return " ".join(named) or "nothing"


def episode_description(spec: dict) -> dict | None:
    """What episode ``spec`` (a dict) asks for, as reading fields {category, color, room,
    anchor}: its ``description`` when it has one (a hand-written request), else what
    :func:`~vla_gr.envs.instructions.parse_instruction` finds in its instruction; None when
    that finds no category."""
    from vla_gr.envs.instructions import parse_instruction

    fields = spec.get("description")
    if fields is None:
        fields = parse_instruction(spec["instruction"])
        if fields["category"] is None:
            return None
    return {mine: fields[theirs] for mine, theirs in COMPARED_FIELDS}


def reading_mismatches(rows: Sequence[dict], limit: int = MISMATCHES_LISTED) -> dict:
    """Rows whose reading differs from the episode's description in any field: how many, and
    the first ``limit`` as {episode, request, reading, description} (reading and description
    as {category, color, room, anchor}; the reading also with ``understood``)."""
    listed, count = [], 0
    for r in readings(rows):
        want = episode_description(r["spec"])
        got = {k: r["reading"].get(k) for k, _ in COMPARED_FIELDS}
        if want is None or got == want:
            continue
        count += 1
        if len(listed) < limit:
            listed.append(
                {
                    "episode": r["episode_index"],
                    "request": r["spec"]["instruction"],
                    "reading": {**got, "understood": r["reading"]["understood"]},
                    "description": want,
                }
            )
    return {"episodes": count, "listed": listed}


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
    normal = [r for r in rows if not is_absent(r)]  # SR / SPL and the rest: normal episodes
    return {
        **header,
        "metrics": overall(normal),
        "breakdowns": {key: breakdown(normal, key) for key in BREAKDOWNS},
        "failure_causes": cause_counts(normal),
        "wrong_stops": wrong_stop_counts(normal),
        "rejected_goals": rejected_goal_counts(normal),
        "low_goal_confidence": low_confidence_episodes(normal),
        "declared": declared_counts(normal),
        "absent_objects": absent_objects(rows),
        "requests_read": len(readings(rows)),
        "not_understood": not_understood_count(rows),
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
