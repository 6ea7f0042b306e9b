"""Measure a rule that changes few episodes: rerun only the episodes where it fired.

An episode runs the same steps whenever the agent decides the same, so a rule that is
switched on changes only the episodes where it acted. Run the split once with the rule on,
then without it on just those episodes, and put the two together::

    vla-gr eval checkpoint=checkpoints/vla_gr_cpu split=val first_episode=3800 \\
        num_episodes=200 workers=2 output_dir=runs/on \\
        "eval.model_overrides=['navigator.approach.unreachable_steps=200']"
    python benchmarks/rerun_fired.py episodes runs/on --reason unreachable --out fired.jsonl
    vla-gr eval checkpoint=checkpoints/vla_gr_cpu episodes=fired.jsonl workers=2 \\
        output_dir=runs/off
    python benchmarks/rerun_fired.py merge runs/on runs/off

``episodes`` writes the specs of the episodes in which S2 rejected a goal for ``--reason``
(the rows' ``rejected_goals``; "any" for any reason; "room_map_kept" where the room map kept a
goal the room check's last ticks would have rejected), with ``--declared`` only those that ended
in that declared outcome (``not_found``: where ``navigator.not_found.second_look`` acts);
``merge`` prints SR, SPL and collision rate of the run with the rule and of the same episodes
without it (the first run's rows, those of the second in their place), and the episodes won
and lost.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vla_gr.envs.episodes import EpisodeSpec, save_episodes
from vla_gr.envs.metrics import aggregate
from vla_gr.evaluation.runner import read_rows


def fired_specs(run_dir: Path, reason: str, declared: str | None = None) -> list[EpisodeSpec]:
    """Specs of the episodes of ``run_dir`` in which a goal was rejected for ``reason``
    ("any": for any reason) and, with ``declared``, that ended in that declared outcome."""
    rows = read_rows(run_dir / "episodes.jsonl")
    if not rows:
        raise SystemExit(f"{run_dir}/episodes.jsonl holds no episodes")
    if reason == "room_map_kept":  # not a rejection: the room map kept a goal
        fired = [r for r in rows if r.get("agent", {}).get("room_map_kept", 0) > 0]
    else:
        fired = [
            r for r in rows if any(reason in ("any", g.get("reason")) for g in r["rejected_goals"])
        ]
    return [
        EpisodeSpec.from_dict(r["spec"]) for r in fired if declared in (None, r.get("declared"))
    ]


def merge(on_dir: Path, off_dir: Path) -> dict:
    """The run's metrics (:func:`~vla_gr.envs.metrics.aggregate`: SR, SPL, collision rate, ...)
    with the rule (``on_dir``) and without it (``off_dir``'s rows in place of the same
    episodes), and the episode ids won and lost by the rule."""
    on = {r["episode_id"]: r for r in read_rows(on_dir / "episodes.jsonl")}
    off = {r["episode_id"]: r for r in read_rows(off_dir / "episodes.jsonl")}
    if not set(off) <= set(on):
        raise SystemExit(f"{off_dir} holds episodes that {on_dir} does not")
    without = {**on, **off}
    won = sorted(k for k in off if on[k]["metrics"]["success"] > off[k]["metrics"]["success"])
    lost = sorted(k for k in off if on[k]["metrics"]["success"] < off[k]["metrics"]["success"])
    return {
        "episodes": len(on),
        "rerun": len(off),
        "with_rule": aggregate([r["metrics"] for r in on.values()]),
        "without_rule": aggregate([r["metrics"] for r in without.values()]),
        "won": won,
        "lost": lost,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ep = sub.add_parser("episodes", help="specs of the episodes where the rule fired")
    ep.add_argument("run_dir", type=Path)
    ep.add_argument(
        "--reason", required=True, help="a rejection reason (unreachable, ...; any; room_map_kept)"
    )
    ep.add_argument("--declared", help="only episodes ending in this declared outcome (not_found)")
    ep.add_argument("--out", type=Path, required=True)
    mg = sub.add_parser("merge", help="the run with the rule against the same without it")
    mg.add_argument("on_dir", type=Path)
    mg.add_argument("off_dir", type=Path)
    args = parser.parse_args()
    if args.command == "episodes":
        specs = fired_specs(args.run_dir, args.reason, args.declared)
        save_episodes(args.out, specs)
        print(f"{len(specs)} episodes with a {args.reason!r} rejection -> {args.out}")
        return
    m = merge(args.on_dir, args.off_dir)
    print(f"{m['episodes']} episodes, {m['rerun']} rerun without the rule")
    print("| | SR | SPL | collision rate |\n|---|---|---|---|")
    for name in ("with_rule", "without_rule"):
        a = m[name]
        print(f"| {name.replace('_', ' ')} | {a['success']:.3f} | {a['spl']:.3f} | "
              f"{a['collision_rate']:.4f} |")  # fmt: skip
    print(f"won {len(m['won'])}: {m['won']}\nlost {len(m['lost'])}: {m['lost']}")


if __name__ == "__main__":
    main()
