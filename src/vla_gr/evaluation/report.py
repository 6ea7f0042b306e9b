"""``report.md`` of an eval run: the table, breakdown bar charts, top-down pictures, GIFs.

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
from vla_gr.evaluation.summary import BREAKDOWNS, LOW_GOAL_CONFIDENCE

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
    reworded = metrics.get("reworded_instructions") or {}
    if reworded:
        lines += [
            "",
            f"**Reworded instructions**: S2 read {reworded['episodes']} instruction(s) in "
            f"template words (instruction lexicon; SR {reworded['success']:.3f} on them):",
            "",
            "| episode | instruction | read as |",
            "|---|---|---|",
        ]
        lines += [
            f"| {r['episode']} | {r['instruction']} | {r['read_as']} |"
            for r in reworded["listed"][:10]
        ]
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
