"""Paraphrased instructions for robustness checks: synonyms and phrasings the templates never use.

:func:`paraphrase` keeps what an instruction says about its goal (category, colour, room,
neighbour: :func:`~vla_gr.envs.instructions.parse_instruction`) and says it differently:
"couch" for sofa, "television" for tv, "the chair that is red", "go into the kitchen and
find ...". None of these words or sentence shapes occur in
:data:`~vla_gr.envs.instructions.TEMPLATES`, so an agent evaluated on them meets language it
was never trained on. :func:`paraphrase_episodes` rewrites a list of episode specs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from vla_gr.envs.episodes import EpisodeSpec
from vla_gr.envs.instructions import parse_instruction

__all__ = ["SYNONYMS", "paraphrase", "paraphrase_episodes"]

#: Category -> words for it that the templates never use.
SYNONYMS: dict[str, tuple[str, ...]] = {
    "chair": ("seat", "armchair"),
    "sofa": ("couch", "settee"),
    "bed": ("bunk", "mattress"),
    "toilet": ("loo", "lavatory"),
    "tv_monitor": ("television", "telly"),
    "plant": ("houseplant", "flowerpot"),
    "table": ("desk",),
    "cabinet": ("cupboard", "dresser"),
}
_ROOM_WORDS = {"living_room": "lounge", "hallway": "corridor", "office": "study"}
_NEAR_WORDS = ("right beside", "close to", "next to where you see")


def _room(room: str, rng: np.random.Generator) -> str:
    word = room.replace("_", " ")
    return _ROOM_WORDS.get(room, word) if rng.random() < 0.5 else word


def paraphrase(instruction: str, rng: np.random.Generator) -> str:
    """A paraphrase of ``instruction`` (a template instruction) that names the same goal.

    Raises ``ValueError`` when the instruction names no known category.
    """
    parts = parse_instruction(instruction)
    category = parts["category"]
    if category is None:
        raise ValueError(f"instruction {instruction!r} names no known category")
    noun = str(rng.choice(SYNONYMS[category]))
    color, room, near = parts["color"], parts["room"], parts["near"]
    subject = f"the {noun} that is {color}" if color else f"the {noun}"
    if near:
        subject += f" {rng.choice(_NEAR_WORDS)} the {rng.choice(SYNONYMS[near])}"
    if room:
        shapes = (
            f"go into the {_room(room, rng)} and find {subject}",
            f"in the {_room(room, rng)} there is {subject}; bring me there",
            f"head for the {_room(room, rng)}, then look for {subject}",
        )
    else:
        shapes = (
            f"search the house for {subject}",
            f"where is {subject}? go there",
            f"i need you next to {subject}",
        )
    return str(rng.choice(shapes))


def paraphrase_episodes(specs: Sequence[EpisodeSpec], seed: int = 0) -> list[EpisodeSpec]:
    """The same episodes with paraphrased instructions (deterministic for a ``seed``)."""
    rng = np.random.default_rng(seed)
    return [dataclasses.replace(s, instruction=paraphrase(s.instruction, rng)) for s in specs]
