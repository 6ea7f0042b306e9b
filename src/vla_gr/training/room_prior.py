"""Learn where categories stand in houses, for the navigator's ``room_search``
(:mod:`vla_gr.agent.navigator.room_search`): from the training houses, how often a room of each
type holds an object of each goal category, and how common each room type is.

Counted over ``houses`` houses of a split (the training split by default), their number of
rooms cycling 1..6; ``presence[c][r] = (rooms of type r holding a c + 1) / (rooms of type r +
2)`` (a Beta(1, 1) prior: a type never seen is an even chance, a count of zero is not a
certainty), ``room_share[r]`` = the type's share of all rooms. Nothing is written by hand:
houses generated differently give other tables.

    python -m vla_gr.training.room_prior checkpoints/vla_gr_cpu outputs/room_search \
        --houses 1200 [--keep 0.5] [--radius 1.5]

writes the checkpoint with ``navigator.room_search`` on and the tables filled in.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["fit_room_prior", "room_search_overrides"]

MAX_ROOMS = 6


def fit_room_prior(
    houses: int = 1200,
    split: str = "train",
    categories: Sequence[str] | None = None,
    room_types: Sequence[str] | None = None,
    generate=None,
) -> dict:
    """``{"categories": [...], "room_types": [...], "presence": [[P per room type] per
    category], "room_share": [...], "houses": n, "rooms": n}`` counted over ``houses`` houses
    of ``split`` (rooms cycling 1..6). ``generate(seed, num_rooms) -> House`` makes a house
    (the world's generator by default)."""
    from vla_gr.envs.house import generate_house, split_seed
    from vla_gr.envs.scene import GOAL_CATEGORIES, ROOM_TYPES

    categories = list(categories or GOAL_CATEGORIES)
    room_types = list(room_types or ROOM_TYPES)
    generate = generate or (lambda seed, rooms: generate_house(seed, num_rooms=rooms))
    if houses < 1:
        raise ValueError(f"houses={houses} must be >= 1")
    rooms = np.zeros(len(room_types))  # (R,) rooms of each type
    holding = np.zeros((len(categories), len(room_types)))  # (C, R) of them holding a c
    for k in range(houses):
        house = generate(split_seed(split, k), 1 + k % MAX_ROOMS)
        for room in house.rooms:
            if room.room_type not in room_types:
                continue
            r = room_types.index(room.room_type)
            rooms[r] += 1
            held = {o.category for o in house.objects if o.room_index == room.index}
            for c, category in enumerate(categories):
                holding[c, r] += category in held
    presence = (holding + 1.0) / (rooms[None, :] + 2.0)  # (C, R)
    return {
        "categories": categories,
        "room_types": room_types,
        "presence": [[round(float(v), 4) for v in row] for row in presence],
        "room_share": [round(float(v), 4) for v in rooms / max(rooms.sum(), 1.0)],
        "houses": int(houses),
        "rooms": int(rooms.sum()),
    }


def room_search_overrides(prior: dict, **settings) -> list[str]:
    """Model overrides (``navigator.room_search.*``) that turn room search on with ``prior``
    (:func:`fit_room_prior`) and any other settings of the section (``keep``, ``radius``)."""
    key = "navigator.room_search"

    def listed(values) -> str:
        return "[" + ",".join(str(v) for v in values) + "]"

    out = [f"{key}.enabled=true"]
    out += [f"{key}.{name}={listed(prior[name])}" for name in ("categories", "room_types")]
    out.append(f"{key}.presence=[{','.join(listed(row) for row in prior['presence'])}]")
    out.append(f"{key}.room_share={listed(prior['room_share'])}")
    out += [f"{key}.{name}={value}" for name, value in settings.items()]
    return out


def main(argv: Sequence[str] | None = None) -> None:
    from vla_gr.policy.export import export_pretrained

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint", help="the agent to give room search")
    parser.add_argument("out", help="the checkpoint folder to write")
    parser.add_argument("--houses", type=int, default=1200)
    parser.add_argument("--split", default="train", choices=("train", "val", "test"))
    parser.add_argument("--keep", type=float, default=0.5)
    parser.add_argument("--radius", type=float, default=1.5)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    prior = fit_room_prior(args.houses, args.split)
    log.info("room prior from %d houses (%d rooms): %s", prior["houses"], prior["rooms"], prior)
    overrides = room_search_overrides(prior, keep=args.keep, radius=args.radius)
    export_pretrained(args.checkpoint, Path(args.out), overrides)
    log.info("wrote %s", args.out)


if __name__ == "__main__":
    main()
