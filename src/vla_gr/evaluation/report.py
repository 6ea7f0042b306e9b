"""``report.md`` and ``report.html`` of an eval run: the table, breakdown bar charts, failure
causes, requests not understood, absent-object episodes and readings that differ from their
episode's description, and per pictured episode a top-down PNG and an MP4.

Pictures are made after the run, never in its loop: a selected episode is replayed from its
recorded actions (:mod:`vla_gr.evaluation.video`). ``report.html`` is ``report.md`` rendered
(Python-Markdown), each video link an inline player; open it in a browser from the run folder.
"""

from __future__ import annotations

import html
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vla_gr.envs.metrics import format_table
from vla_gr.evaluation.causes import CAUSES
from vla_gr.evaluation.summary import (
    BREAKDOWNS,
    LOW_GOAL_CONFIDENCE,
    fields_text,
    reading_mismatches,
)

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
    """The headline numbers of one metrics.json (plus decision p50 when measured); a run of
    absent-object episodes alone has none but ``episodes`` (0)."""
    row = {k: metrics["metrics"][k] for k in TABLE_KEYS if k in metrics["metrics"]}
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


def replay_pictures(
    env, row: dict, out_dir: Path, panel: int, stride: int, video: bool = True
) -> dict[str, str | None]:
    """Write ``row``'s top-down PNG (path, start, goal, scale) and, with ``video``, its MP4
    replayed in ``env`` (:func:`~vla_gr.evaluation.video.episode_clip`); their file names
    (``{"topdown": ..., "video": ... or None}``)."""
    from vla_gr.envs.visualize import save_mp4, save_top_down_png
    from vla_gr.evaluation.video import episode_clip, reset_to

    stem = f"episode_{row['episode_index']:04d}_{row['cause'] or 'success'}"
    files: dict[str, str | None] = {"topdown": f"{stem}_topdown.png", "video": None}
    xy = np.asarray(row["trace"]["xy"])  # (T + 1, 2)
    if video:
        frames, fps = episode_clip(env, row, panel, stride)
        files["video"] = save_mp4(out_dir / f"{stem}.mp4", frames, fps).name
        robot = env.unwrapped.robot_pose_world()  # (3,) where the replay ended, with heading
    else:
        reset_to(env, row)
        robot = xy[-1]
    u = env.unwrapped
    save_top_down_png(
        out_dir / files["topdown"],
        u.house,
        trajectory=xy,
        start=np.asarray(u.start_pose_world, dtype=np.float64),
        goal_id=u.goal_id,
        robot=robot,
        size=256,
    )
    return files


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


def absent_lines(metrics: dict) -> list[str]:
    """The report's table of absent-object episodes ([] for a run without any)."""
    a = metrics.get("absent_objects") or {}
    n = a.get("episodes", 0)
    if not n:
        return []
    spread = a["steps_to_declare"]
    median = "-" if spread is None else f"{spread['median']:.0f}"
    return [
        "",
        "## Absent objects",
        "",
        f"{n} episode(s) asked for an object the house does not have (not in SR / SPL):",
        "",
        "| declared not found | false STOPs | timeouts | not understood "
        "| median steps to declare |",
        "|---|---|---|---|---|",
        f"| {a['declared_not_found']} ({a['declared_not_found_rate']:.1%}) | {a['false_stops']} "
        f"({a['false_stop_rate']:.1%}) | {a['timeouts']} | {a['not_understood']} | {median} |",
    ]


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
        reading = fields_text(m["reading"]) + (
            "" if m["reading"]["understood"] else " (not understood)"
        )
        described = fields_text(m["description"])
        lines.append(f"| {m['episode']} | {_cell(m['request'])} | {reading} | {described} |")
    return lines


def write_report(out_dir: Path, metrics: dict, rows: Sequence[dict], pictures: dict) -> Path:
    """Write ``report.md``, ``report.html`` and ``breakdowns.png`` into ``out_dir``; returns
    the md path. ``pictures``: episode index -> :func:`replay_pictures`'s file names."""
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
        groups = metrics["breakdowns"][key]  # {} on a run of absent-object episodes alone
        lines += [f"### {key}", "", format_table(groups) if groups else "(no normal episode)", ""]
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
    lines += absent_lines(metrics)
    lines += reading_lines(rows)
    lines += ["", "## Latency per decision (ms, batch 1)", ""]
    if metrics["latency_ms"]:
        lines += [format_table(metrics["latency_ms"]), ""]
    if metrics["parameters"]:
        lines += ["## Parameters", "", format_table({"count": metrics["parameters"]}), ""]
    lines += episode_lines(rows, pictures)
    text = "\n".join(lines)
    path = out_dir / "report.md"
    path.write_text(text)
    (out_dir / "report.html").write_text(html_page(text, lines[0].lstrip("# ")))
    return path


def episode_lines(rows: Sequence[dict], pictures: dict) -> list[str]:
    """The report's pictured episodes: outcome, request, reading and numbers, a link to the
    video and the top-down picture ([] when none is pictured)."""
    from vla_gr.evaluation.video import reading_line

    if not pictures:
        return []
    lines = ["", "## Episodes", ""]
    by_index = {r["episode_index"]: r for r in rows}
    for index, files in sorted(pictures.items()):
        row = by_index[index]
        m = row["metrics"]
        video = f"[video]({files['video']})" if files["video"] else "(no video: no ffmpeg)"
        lines += [
            f"### episode {index}: {row['cause'] or 'success'}",
            "",
            f"{_cell(row['spec']['instruction'])} ({m['steps']} steps, final distance "
            f"{m['distance_to_goal']:.2f} m; {_cell(reading_line(row.get('reading')))})",
            "",
            video,
            "",
            f"![top-down]({files['topdown']})",
            "",
        ]
    return lines


#: A video link of :func:`episode_lines` as Python-Markdown writes it.
_VIDEO_LINK = re.compile(r'<a href="([^"<>]+\.mp4)">video</a>')
_VIDEO_TAG = r'<video src="\1" controls muted loop playsinline preload="auto"></video>'
_STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;"
    "color:#222}table{border-collapse:collapse;margin:.5em 0;display:block;overflow-x:auto}"
    "th,td{border:1px solid #ccc;"
    "padding:.2em .6em}th{background:#f0f0f0}tbody tr:nth-child(even){background:#fafafa}"
    "img,video{max-width:100%}video{display:block;background:#000}"
)


def html_page(markdown_text: str, title: str) -> str:
    """``markdown_text`` (the report's) as a standalone HTML page: its tables and pictures,
    each ``[video](x.mp4)`` link a player. HTML written in the text (a request's, say) is
    shown as text, not run."""
    import markdown

    md = markdown.Markdown(extensions=["tables"])
    md.preprocessors.deregister("html_block")
    md.inlinePatterns.deregister("html")
    body = _VIDEO_LINK.sub(_VIDEO_TAG, md.convert(markdown_text))
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>\n"
        f"<body>\n{body}\n</body></html>\n"
    )
