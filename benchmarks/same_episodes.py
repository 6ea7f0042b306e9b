"""Are two evaluations of an agent the same, episode for episode? (timings excepted)

A redesign that must not change behaviour is checked by recording, before the change, a
*fingerprint* of every row of a ``vla-gr eval`` run (its ``episodes.jsonl``) and comparing
the same command's rows after the change::

    python benchmarks/same_episodes.py fingerprint <eval run> <fingerprints.jsonl>
    python benchmarks/same_episodes.py compare <fingerprints.jsonl> <eval run>

A fingerprint keeps the row's outcome (success, SPL, soft SPL, distance, collisions, path
length, steps, failure cause, STOP), what the agent concluded (its episode summary) and the
SHA-256 of its actions and trajectory, so any change of a single action shows. ``compare``
prints the rows that differ and the fields that do, and exits 1 when any does.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

OUTCOME = ("stopped", "cause", "goal_category", "instruction_kind", "num_rooms")


def _digest(value) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True).encode()).hexdigest()


def fingerprint(row: dict) -> dict:
    """The parts of one ``episodes.jsonl`` row that behaviour decides (no timings)."""
    return {
        "episode_index": row["episode_index"],
        "episode_id": row["episode_id"],
        "metrics": row["metrics"],
        **{k: row.get(k) for k in OUTCOME},
        "agent": row.get("agent", {}),
        "actions_sha256": _digest(row["actions"]),
        "trace_sha256": _digest(row["trace"]),
    }


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def run_rows(run: Path) -> list[dict]:
    """Fingerprints of an eval run folder (or of an ``episodes.jsonl`` file)."""
    path = run / "episodes.jsonl" if run.is_dir() else run
    return [fingerprint(r) for r in read_jsonl(path)]


def differences(before: list[dict], after: list[dict]) -> dict[int, list[str]]:
    """Episode index -> the fingerprint fields that differ (``missing`` when one side lacks
    the episode)."""
    a = {r["episode_index"]: r for r in before}
    b = {r["episode_index"]: r for r in after}
    out: dict[int, list[str]] = {}
    for index in sorted(set(a) | set(b)):
        if index not in a or index not in b:
            out[index] = ["missing"]
            continue
        fields = [k for k in a[index] if a[index][k] != b[index].get(k)]
        fields += [f"metrics.{k}" for k in a[index]["metrics"] if k not in b[index]["metrics"]]
        if fields:
            out[index] = fields
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    fp = sub.add_parser("fingerprint", help="write the fingerprints of an eval run")
    fp.add_argument("run", type=Path)
    fp.add_argument("out", type=Path)
    cmp = sub.add_parser("compare", help="compare recorded fingerprints with an eval run")
    cmp.add_argument("fingerprints", type=Path)
    cmp.add_argument("run", type=Path)
    args = parser.parse_args(argv)
    if args.command == "fingerprint":
        rows = run_rows(args.run)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))
        print(f"{len(rows)} fingerprints -> {args.out}")
        return 0
    before, after = read_jsonl(args.fingerprints), run_rows(args.run)
    diff = differences(before, after)
    same = len(set(r["episode_index"] for r in before)) - len(diff)
    print(f"{args.run}: {same} of {len(before)} episodes identical to {args.fingerprints}")
    for index, fields in diff.items():
        print(f"  episode {index}: {', '.join(fields)}")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())
