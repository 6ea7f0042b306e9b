"""An episodes file of absent-object episodes (and, with ``--with-normal``, each one's normal
twin in the same house), in houses of 1-6 rooms drawn evenly, for ``vla-gr eval``.

    python benchmarks/absent_episodes.py --split val --first 0 --count 20 --with-normal \
        --out outputs/episodes/val_absent_0-19.jsonl
    vla-gr eval checkpoint=checkpoints/vla_gr_cpu episodes=outputs/episodes/val_absent_0-19.jsonl

Index ``first + k`` of ``split`` is drawn with ``1 + k % 6`` rooms: its absent-object episode
(:func:`vla_gr.envs.absent.sample_absent_episode`: a colour no object of a goal category has,
or a goal category the house lacks) and, with ``--with-normal``, the split's episode of that
index in the same house (:func:`vla_gr.envs.episodes.sample_episode`). An index whose house
hosts no such episode is skipped. ``metrics.json`` of the eval then carries both: SR / SPL and
false "not found" declarations of the normal episodes, and the ``absent_objects`` block.
"""

from __future__ import annotations

import argparse
from collections import Counter

from vla_gr.envs.absent import sample_absent_episode
from vla_gr.envs.episodes import NoEpisodeError, sample_episode, save_episodes

MAX_ROOMS = 6


def absent_episodes(split: str, first: int, count: int, with_normal: bool) -> tuple[list, Counter]:
    """(the specs of indices ``first`` .. ``first + count - 1``, rooms cycling 1..6; how many
    of each kind were written or skipped)."""
    specs, counts = [], Counter()
    for k in range(count):
        index, rooms = first + k, 1 + k % MAX_ROOMS
        samplers = [("absent", sample_absent_episode)]
        if with_normal:
            samplers.append(("normal", sample_episode))
        for kind, sample in samplers:
            try:
                specs.append(sample(split, index, num_rooms=rooms))
                counts[kind] += 1
            except NoEpisodeError:
                counts[f"{kind} skipped"] += 1
    return specs, counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--first", type=int, required=True)
    parser.add_argument("--count", type=int, required=True, help="split indices drawn")
    parser.add_argument("--with-normal", action="store_true", help="each index's normal twin too")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    specs, counts = absent_episodes(args.split, args.first, args.count, args.with_normal)
    path = save_episodes(args.out, specs)
    print(
        f"| {args.split} {args.first}-{args.first + args.count - 1} | "
        + " | ".join(f"{k} {v}" for k, v in sorted(counts.items()))
        + f" | -> {path} |"
    )


if __name__ == "__main__":
    main()
