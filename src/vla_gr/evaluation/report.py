"""``report.md`` of an eval run: the table, breakdown bar charts, failure causes, requests
not understood and readings that differ from their episode's description, top-down pictures,
GIFs.

Pictures are made after the run, never in its loop: a selected episode is replayed from its
recorded actions (the env is deterministic given ``reset(seed=k)``, noise included) while
frames are rendered at GIF size.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vla_gr.envs.metrics import format_table
from vla_gr.evaluation.causes import CAUSES
from vla_gr.evaluation.summary import (
    BREAKDOWNS,
    COMPARED_FIELDS,
    LOW_GOAL_CONFIDENCE,
    reading_mismatches,
)

log = logging.getLogger(__name__)

TABLE_KEYS = (
    "success",
    "spl",
    "soft_spl",
    "distance_to_goal",
    "collision_rate",
    "collision_episode_share",
    "path_length",
    "steps",
)


def table_row(metrics: dict) -> dict:
    """The headline numbers of one metrics.json (plus decision p50 when measured)."""
    row = {k: metrics["metrics"][k] for k in TABLE_KEYS}
    row["episodes"] = metrics["metrics"]["episodes"]
    decision = metrics.get("latency_ms", {}).get("decision")
    if decision:
        row["decision_p50_ms"] = decision["p50"]
    return row


def agent_row(metrics: dict) -> dict:
    """What an agent of a comparison is: the registered agent, checkpoint and overrides."""
    return {
        "agent": metrics.get("base_agent", metrics["agent"]),
        "checkpoint": metrics["checkpoint"],
        "model_overrides": list(metrics["model_overrides"]),
    }


def agents_table(setups: dict[str, dict]) -> str:
    """Markdown table of :func:`agent_row` entries ("-" where there is none)."""
    cells = {
        name: {
            "agent": s["agent"],
            "checkpoint": s["checkpoint"] or "-",
            "model_overrides": " ".join(s["model_overrides"]) or "-",
        }
        for name, s in setups.items()
    }
    return format_table(cells)


def select_episodes(rows: Sequence[dict], successes: int, per_cause: int) -> list[dict]:
    """The first ``successes`` successful rows and the first ``per_cause`` rows of each cause."""
    chosen = [r for r in rows if r["cause"] is None][:successes]
    for cause in CAUSES:
        chosen += [r for r in rows if r["cause"] == cause][:per_cause]
    return sorted(chosen, key=lambda r: r["episode_index"])


def replay_pictures(env, row: dict, out_dir: Path, panel: int, stride: int) -> dict[str, str]:
    """Replay ``row``'s actions in ``env``; write its GIF and top-down PNG; their names."""
    from vla_gr.envs.visualize import EpisodeRecorder, save_top_down_png

    env.reset(seed=row["episode_index"])
    u = env.unwrapped
    goal_id = int(u.goal.instance_id)
    start = np.asarray(u.start_pose_world, dtype=np.float64)  # (3,)
    recorder = EpisodeRecorder(u.house, goal_id, start, panel, float(u.max_depth))
    recorder.add(*u.render_rgbd(panel), u.robot_pose_world())
    actions = row["actions"]
    for t, action in enumerate(actions, start=1):
        if t == len(actions) and row.get("declared"):
            u.declare(row["declared"])  # how the episode ended: no motion, no STOP
        else:
            env.step(np.asarray(action, dtype=np.float32))
        if t % stride == 0 or t == len(actions):
            recorder.add(*u.render_rgbd(panel), u.robot_pose_world())
    final = u.robot_pose_world()[:2]
    if not np.allclose(final, row["trace"]["xy"][-1], atol=1e-3):
        log.warning("episode %d: the replay ended elsewhere", row["episode_index"])
    stem = f"episode_{row['episode_index']:04d}_{row['cause'] or 'success'}"
    recorder.save(out_dir / f"{stem}.gif")
    save_top_down_png(
        out_dir / f"{stem}_topdown.png",
        u.house,
        trajectory=np.asarray(row["trace"]["xy"]),
        start=start,
        goal_id=goal_id,
        robot=u.robot_pose_world(),
        size=256,
    )
    return {"gif": f"{stem}.gif", "topdown": f"{stem}_topdown.png"}


def breakdown_chart(metrics: dict, path: Path) -> Path:
    """Bar charts (PNG) of SR and SPL per breakdown value, one panel per breakdown."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(BREAKDOWNS), figsize=(5 * len(BREAKDOWNS), 3.5))
    for ax, key in zip(axes, BREAKDOWNS):
        groups = metrics["breakdowns"][key]
        names = list(groups)
        x = np.arange(len(names))
        ax.bar(x - 0.2, [groups[n]["success"] for n in names], 0.4, label="SR")
        ax.bar(x + 0.2, [groups[n]["spl"] for n in names], 0.4, label="SPL")
        ax.set_xticks(x, [f"{n}\n({groups[n]['episodes']})" for n in names], fontsize=8)
        ax.set_ylim(0, 1)
        ax.set_title(key)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _cell(text: str) -> str:
    """``text`` as one markdown table cell (whitespace runs to one space, pipes escaped)."""
    text = " ".join(str(text).split()).replace("|", "\\|")
    return text or "(blank)"


def _fields(fields: dict) -> str:
    """'category=chair color=red' for the named fields ('nothing' when none is)."""
    named = [f"{k}={fields[k]}" for k, _ in COMPARED_FIELDS if fields.get(k) is not None]
    return " ".join(named) or "nothing"


def declared_lines(metrics: dict) -> list[str]:
    """The report's lines on declared outcomes and requests not understood ([] for a run
    whose agent declared nothing and read no request)."""
    declared = metrics.get("declared") or {}
    read = metrics.get("requests_read", 0)
    if not any(declared.values()) and not read:
        return []
    lines = ["", "## Requests and declared outcomes", ""]
    if read:
        lines.append(f"- {metrics['not_understood']} of {read} requests were not fully understood.")
    if any(declared.values()):
        what = ", ".join(f"{outcome} {n}" for outcome, n in declared.items())
        lines.append(f"- Episodes the agent ended by declaring an outcome (no STOP): {what}.")
    return lines


def reading_lines(rows: Sequence[dict]) -> list[str]:
    """The report's table of readings that differ from their episode's description (the
    first ``MISMATCHES_LISTED``; [] when every reading agrees or no row has one)."""
    mismatches = reading_mismatches(rows)
    if not mismatches["episodes"]:
        return []
    lines = [
        "",
        "## Readings that differ from the episode's description",
        "",
        f"{mismatches['episodes']} reading(s) differ in category, colour, room or anchor"
        f" (the first {len(mismatches['listed'])} listed):",
        "",
        "| episode | request | reading | description |",
        "|---|---|---|---|",
    ]
    for m in mismatches["listed"]:
        reading = _fields(m["reading"]) + (
            "" if m["reading"]["understood"] else " (not understood)"
        )
        lines.append(
            f"| {m['episode']} | {_cell(m['request'])} | {reading} | {_fields(m['description'])} |"
        )
    return lines


def write_report(out_dir: Path, metrics: dict, rows: Sequence[dict], pictures: dict) -> Path:
    """Write ``report.md`` (and ``breakdowns.png``) into ``out_dir``; returns the md path."""
    chart = breakdown_chart(metrics, out_dir / "breakdowns.png")
    lines = [
        f"# Evaluation: {metrics['agent']} on {metrics['episodes_source']}",
        "",
        format_table({metrics["agent"]: table_row(metrics)}),
        "",
        "## Breakdowns (SR / SPL, episodes in brackets)",
        "",
        f"![breakdowns]({chart.name})",
        "",
    ]
    for key in BREAKDOWNS:
        lines += [f"### {key}", "", format_table(metrics["breakdowns"][key]), ""]
    lines += ["## Failure causes", "", "| cause | episodes |", "|---|---|"]
    lines += [f"| {c} | {n} |" for c, n in metrics["failure_causes"].items()]
    wrong = metrics.get("wrong_stops") or {}
    if any(wrong.values()):
        lines += ["", "Wrong STOPs by the object nearest to where the robot stopped:", ""]
        lines += ["| next to | episodes |", "|---|---|"]
        lines += [f"| {kind} | {n} |" for kind, n in wrong.items()]
    rejected = dict(metrics.get("rejected_goals") or {})
    failed_after = rejected.pop("episodes_failed_after_rejecting_the_goal", 0)
    if rejected:
        kinds = list(next(iter(rejected.values())))
        lines += ["", "Goals the planner rejected, by reason and by what they were:", ""]
        lines += ["| reason | " + " | ".join(kinds) + " |", "|---" * (len(kinds) + 1) + "|"]
        lines += [f"| {why} | " + " | ".join(str(n[k]) for k in kinds) + " |"
                  for why, n in rejected.items()]  # fmt: skip
        lines += ["", f"Failed episodes that had rejected the goal itself: {failed_after}"]
    low = metrics.get("low_goal_confidence") or []
    if low:
        lines += [
            "",
            f"**Low goal confidence** in {len(low)} episode(s) (the planner never confirmed "
            f"the instructed object, confidence < {LOW_GOAL_CONFIDENCE}): "
            + ", ".join(str(i) for i in low[:50]),
        ]
    lines += declared_lines(metrics)
    lines += reading_lines(rows)
    lines += ["", "## Latency per decision (ms, batch 1)", ""]
    if metrics["latency_ms"]:
        lines += [format_table(metrics["latency_ms"]), ""]
    if metrics["parameters"]:
        lines += ["## Parameters", "", format_table({"count": metrics["parameters"]}), ""]
    if pictures:
        lines += ["## Episodes", ""]
        by_index = {r["episode_index"]: r for r in rows}
        for index, files in sorted(pictures.items()):
            row = by_index[index]
            lines += [
                f"### episode {index}: {row['cause'] or 'success'}",
                "",
                f"{row['spec']['instruction']} ({row['metrics']['steps']} steps, "
                f"final distance {row['metrics']['distance_to_goal']:.2f} m)",
                "",
                f"![top-down]({files['topdown']}) ![episode]({files['gif']})",
                "",
            ]
    path = out_dir / "report.md"
    path.write_text("\n".join(lines))
    return path
