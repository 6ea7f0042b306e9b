"""Success of a paraphrased run split by how S2 read each instruction.

    python benchmarks/paraphrase_readings.py [CLEAN_RUN] PARAPHRASED_RUN

Both are ``vla-gr eval`` output folders over the same episodes (e.g. the ``clean`` and
``paraphrase`` runs of ``bench_robustness.py``); without ``CLEAN_RUN`` each episode's
template instruction is drawn again from its split and index
(:func:`~vla_gr.envs.episodes.sample_episode`). For each episode the fields S2 read (goal
category, relation anchor, room type in the row's ``agent.read_as``, or the paraphrase itself
when S2 read it as it was) are compared with the fields of the template instruction the
paraphrase was made from, by the template readers. Each episode falls in the first group that
fits: a wrong room, a wrong category or anchor, a field left empty, every
field right. Prints a markdown table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vla_gr.agent.perception.instruction_reader import read_instruction
from vla_gr.agent.perception.object_category import CATEGORIES
from vla_gr.agent.perception.room_type import ROOM_TYPES
from vla_gr.envs.episodes import sample_episode

GROUPS = ("every field right", "a field left empty", "a wrong category or anchor", "a wrong room")


def _fields(text: str) -> dict:
    reading = read_instruction(text, CATEGORIES, ROOM_TYPES)
    return {"category": reading.category, "anchor": reading.anchor, "room": reading.room}


def reading_group(said: str, read: str) -> str:
    """The group of an episode whose template instruction ``said`` S2 read as ``read``."""
    truth, got = _fields(said), _fields(read)
    if got["room"] is not None and got["room"] != truth["room"]:
        return "a wrong room"
    if any(got[k] is not None and got[k] != truth[k] for k in ("category", "anchor")):
        return "a wrong category or anchor"
    if got != truth:
        return "a field left empty"
    return "every field right"


def _rows(folder: str) -> dict[int, dict]:
    lines = (Path(folder) / "episodes.jsonl").read_text().splitlines()
    return {r["episode_index"]: r for r in map(json.loads, lines)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "runs", nargs="+", metavar="RUN", help="[CLEAN_RUN] PARAPHRASED_RUN: eval folders"
    )
    args = parser.parse_args()
    if len(args.runs) > 2:
        parser.error(f"at most two runs (CLEAN_RUN PARAPHRASED_RUN), got {len(args.runs)}")
    para = _rows(args.runs[-1])
    if len(args.runs) == 2:
        said = {i: r["spec"]["instruction"] for i, r in _rows(args.runs[0]).items()}
    else:
        said = {i: sample_episode(r["spec"]["split"], i).instruction for i, r in para.items()}
    counts = {g: [0, 0] for g in GROUPS}  # group -> [episodes, successes]
    for index, row in para.items():
        read = row.get("agent", {}).get("read_as") or row["spec"]["instruction"]
        group = reading_group(said[index], read)
        counts[group][0] += 1
        counts[group][1] += int(row["metrics"]["success"] > 0)
    lines = ["| S2's reading | episodes | SR |", "|---|---|---|"]
    for group, (n, won) in counts.items():
        lines.append(f"| {group} | {n} | {won / n:.3f} |" if n else f"| {group} | 0 | |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
