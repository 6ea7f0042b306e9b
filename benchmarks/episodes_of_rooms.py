"""An episodes file in houses of 1-6 rooms drawn evenly, for ``vla-gr eval``.

    python benchmarks/episodes_of_rooms.py --split test --first 50000 --count 900 \
        --out outputs/episodes/test_rooms16_50000.jsonl
    vla-gr eval checkpoint=checkpoints/vla_gr_cpu episodes=outputs/episodes/test_rooms16_50000.jsonl

The k-th episode has ``1 + k % 6`` rooms (``--count`` a multiple of 6 gives as many of each);
episode indices run from ``--first`` on, an index whose house hosts no episode skipped
(:func:`vla_gr.envs.episodes.sample_episodes_rooms_cycling`). The split's own episodes come
from houses of 2-5 rooms; this is how the agent is measured on 1-6.
"""

from __future__ import annotations

import argparse
from collections import Counter

from vla_gr.envs.episodes import sample_episodes_rooms_cycling, save_episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--first", type=int, required=True)
    parser.add_argument("--count", type=int, required=True, help="episodes written")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    specs = sample_episodes_rooms_cycling(args.split, args.first, args.count)
    path = save_episodes(args.out, specs)
    rooms = Counter(spec.num_rooms for spec in specs)
    print(f"{len(specs)} episodes ({dict(sorted(rooms.items()))} by rooms) -> {path}")


if __name__ == "__main__":
    main()
