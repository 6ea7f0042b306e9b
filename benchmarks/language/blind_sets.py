"""Blind request sets: episodes in unseen houses of 1-6 rooms, each with a request written by
hand the way people type it, labelled with the fields it names.

A set is one JSONL file ``benchmarks/language/<name>.jsonl``; each line holds

    {"spec": <EpisodeSpec dict, instruction in the generator's words>,
     "fields": {"category", "color", "room", "near"},   # what the request names (None: not named)
     "request": "<the hand-written request>"}

``fields`` are the generator's fields of the episode (the goal is fixed by the spec, never by
a reader), so a request that names them all describes the goal uniquely.

    python benchmarks/language/blind_sets.py pool --first 20000 --count 150 --out pool.jsonl
    python benchmarks/language/blind_sets.py check benchmarks/language/blind_a.jsonl
    python benchmarks/language/blind_sets.py episodes benchmarks/language/blind_a.jsonl \
        --words request --out /tmp/blind_a_request.jsonl   # then: vla-gr eval episodes=...

``pool`` draws episodes ``first`` .. of the ``test`` split, the number of rooms cycling
1, 2, ..., 6 (houses of 1-6 rooms drawn evenly), and writes them with an empty request.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vla_gr.envs.episodes import EpisodeSpec, sample_episodes_rooms_cycling, save_episodes
from vla_gr.envs.instructions import parse_instruction

FIELDS = ("category", "color", "room", "near")
MAX_ROOMS = 6


def draw_pool(first: int, count: int, split: str = "test") -> list[dict]:
    """``count`` episodes from index ``first`` on, rooms cycling 1..6; unhostable skipped."""
    return [
        {"spec": spec.to_dict(), "fields": parse_instruction(spec.instruction), "request": ""}
        for spec in sample_episodes_rooms_cycling(split, first, count, MAX_ROOMS)
    ]


def load_set(path: str | Path) -> list[dict]:
    """The lines of a blind set, checked: spec loads, fields are the generator's, request set."""
    rows = []
    for lineno, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        row = json.loads(line)
        spec = EpisodeSpec.from_dict(row["spec"])
        if set(row["fields"]) != set(FIELDS):
            raise ValueError(f"{path}:{lineno}: fields must be exactly {list(FIELDS)}")
        if parse_instruction(spec.instruction) != row["fields"]:
            raise ValueError(f"{path}:{lineno}: fields differ from the generator's description")
        if not isinstance(row.get("request"), str):
            raise ValueError(f"{path}:{lineno}: no request")
        if not row["request"].strip() and "kind" not in row:  # "" is a request to refuse
            raise ValueError(f"{path}:{lineno}: empty request")
        rows.append(row)
    return rows


def episodes_file(rows: list[dict], words: str, out: str | Path) -> Path:
    """An episodes file of the set, instruction = the request or the generator's words; a
    request's episode carries the generator's fields as its ``description``."""
    specs = []
    for row in rows:
        record = dict(row["spec"])
        if words == "request":
            record["instruction"] = row["request"]
            record["description"] = dict(row["fields"])
        specs.append(EpisodeSpec.from_dict(record))
    return save_episodes(out, specs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    pool = sub.add_parser("pool", help="draw episodes with empty requests")
    pool.add_argument("--first", type=int, required=True)
    pool.add_argument("--count", type=int, default=150)
    pool.add_argument("--out", required=True)
    check = sub.add_parser("check", help="validate a filled set")
    check.add_argument("path")
    episodes = sub.add_parser("episodes", help="write an episodes file for vla-gr eval")
    episodes.add_argument("path")
    episodes.add_argument("--words", choices=("request", "generator"), required=True)
    episodes.add_argument("--out", required=True)
    args = parser.parse_args()
    if args.command == "pool":
        rows = draw_pool(args.first, args.count)
        Path(args.out).write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
        print(f"{len(rows)} episodes -> {args.out}")
    elif args.command == "check":
        rows = load_set(args.path)
        print(f"{args.path}: {len(rows)} requests, fields match their episodes")
    else:
        path = episodes_file(load_set(args.path), args.words, args.out)
        print(f"{path}")


if __name__ == "__main__":
    main()
