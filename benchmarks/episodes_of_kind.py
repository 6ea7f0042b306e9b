"""An episodes file of one instruction kind, for a focused ``vla-gr eval`` run.

    python benchmarks/episodes_of_kind.py --split val --first 1000 --last 1800 \
        --kind relation --out docs/experiments/eval/episodes/val_relation_1000-1799.jsonl

Samples episodes ``first`` .. ``last - 1`` of ``split`` exactly as the environment does
(same index, same spec), keeps those whose instruction is of ``kind`` ("relation", "room",
"colour" or "category", as :func:`vla_gr.evaluation.runner.instruction_kind` says) and writes
them as a JSONL episodes file; ``vla-gr eval episodes=<file>`` runs them. An index whose house
cannot host an episode is skipped, as collection skips it. Prints how many were kept.
"""

from __future__ import annotations

import argparse
from collections import Counter

from vla_gr.envs.episodes import NoEpisodeError, sample_episode, save_episodes
from vla_gr.evaluation.runner import instruction_kind

KINDS = ("relation", "room", "colour", "category")


def episodes_of_kind(split: str, first: int, last: int, kind: str) -> tuple[list, Counter]:
    """(the specs of ``kind`` among episodes ``first`` .. ``last - 1``, count per kind)."""
    if kind not in KINDS:
        raise ValueError(f"--kind {kind!r} is not one of {', '.join(KINDS)}")
    kept, counts = [], Counter()
    for index in range(first, last):
        try:
            spec = sample_episode(split, index)
        except NoEpisodeError:
            counts["no episode"] += 1
            continue
        spec_kind = instruction_kind(spec.instruction)
        counts[spec_kind] += 1
        if spec_kind == kind:
            kept.append(spec)
    return kept, counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="val")
    parser.add_argument("--first", type=int, required=True)
    parser.add_argument("--last", type=int, required=True, help="one past the last index")
    parser.add_argument("--kind", default="relation", choices=KINDS)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    kept, counts = episodes_of_kind(args.split, args.first, args.last, args.kind)
    path = save_episodes(args.out, kept)
    print(
        f"| {args.split} {args.first}-{args.last - 1} | "
        + " | ".join(f"{k} {v}" for k, v in sorted(counts.items()))
        + f" | kept {len(kept)} -> {path} |"
    )


if __name__ == "__main__":
    main()
