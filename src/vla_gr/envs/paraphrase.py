"""Paraphrased instructions for robustness checks: synonyms and phrasings the templates never use.

:func:`paraphrase` keeps what an instruction says about its goal (category, colour, room,
neighbour: :func:`~vla_gr.envs.instructions.parse_instruction`) and says it differently:
"couch" for sofa, "television" for tv, "the chair that is red", "go into the kitchen and
find ...". None of these words or sentence shapes occur in
:data:`~vla_gr.envs.instructions.TEMPLATES`, so an agent evaluated on them meets language it
was never trained on. :func:`paraphrase_episodes` rewrites a list of episode specs.

Eight vocabularies with no word or shape in common: :data:`HELD_OUT` (what robustness is
measured on), :data:`TRAINING` (for ``training.paraphrase_prob``: the goal head learns that
unseen wording can name the same object, without seeing the held-out words; and for the
instruction reader), :data:`VALIDATION` (for choosing a learned part's settings on unseen
wording without looking at the held-out set), :data:`SECOND_HELD_OUT` (written after
failures on the first held-out set had been read, before any change was measured on it: a
blind measure of a change designed on those failures) and :data:`THIRD_HELD_OUT` (the same
for the second set's failures), :data:`FOURTH_HELD_OUT` (the same for the third set's),
:data:`FIFTH_HELD_OUT` (the same for the fourth set's) and :data:`SIXTH_HELD_OUT` (the same
for the fifth set's).
:data:`VOCABULARIES` names them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vla_gr.envs.episodes import EpisodeSpec
from vla_gr.envs.instructions import parse_instruction

__all__ = [
    "FIFTH_HELD_OUT",
    "FOURTH_HELD_OUT",
    "HELD_OUT",
    "SECOND_HELD_OUT",
    "SIXTH_HELD_OUT",
    "SYNONYMS",
    "THIRD_HELD_OUT",
    "TRAINING",
    "VALIDATION",
    "VOCABULARIES",
    "Vocabulary",
    "paraphrase",
    "paraphrase_episodes",
    "paraphrase_instructions",
]


@dataclass(frozen=True)
class Vocabulary:
    """Words and sentence shapes of one paraphrase set.

    ``room_shapes`` / ``plain_shapes`` are format strings with ``{subject}`` (and ``{room}``);
    ``color_subject`` has ``{noun}`` and ``{color}``.
    """

    synonyms: dict[str, tuple[str, ...]]  # category -> words for it
    room_words: dict[str, str]  # room -> another word for it (used half the time)
    near_words: tuple[str, ...]  # phrasings of "near"
    color_subject: str
    room_shapes: tuple[str, ...]
    plain_shapes: tuple[str, ...]


#: The held-out set: what robustness is measured on. Never train on it.
HELD_OUT = Vocabulary(
    synonyms={
        "chair": ("seat", "armchair"),
        "sofa": ("couch", "settee"),
        "bed": ("bunk", "mattress"),
        "toilet": ("loo", "lavatory"),
        "tv_monitor": ("television", "telly"),
        "plant": ("houseplant", "flowerpot"),
        "table": ("desk",),
        "cabinet": ("cupboard", "dresser"),
    },
    room_words={"living_room": "lounge", "hallway": "corridor", "office": "study"},
    near_words=("right beside", "close to", "next to where you see"),
    color_subject="the {noun} that is {color}",
    room_shapes=(
        "go into the {room} and find {subject}",
        "in the {room} there is {subject}; bring me there",
        "head for the {room}, then look for {subject}",
    ),
    plain_shapes=(
        "search the house for {subject}",
        "where is {subject}? go there",
        "i need you next to {subject}",
    ),
)

#: A second set for training the goal head on unseen wording: no word or shape of
#: :data:`HELD_OUT` (tests/envs/test_paraphrase.py checks it).
TRAINING = Vocabulary(
    synonyms={
        "chair": ("stool", "recliner"),
        "sofa": ("loveseat", "sectional"),
        "bed": ("cot", "daybed"),
        "toilet": ("wc", "commode"),
        "tv_monitor": ("screen", "display"),
        "plant": ("fern", "greenery"),
        "table": ("worktop", "tabletop"),
        "cabinet": ("wardrobe", "sideboard"),
    },
    room_words={"living_room": "family room", "hallway": "passage", "office": "workroom"},
    near_words=("alongside", "by", "adjacent to"),
    color_subject="the {noun} coloured {color}",
    room_shapes=(
        "make your way to the {room}; {subject} is the target",
        "stop by {subject} over in the {room}",
        "{subject} inside the {room}, please",
    ),
    plain_shapes=(
        "your target: {subject}",
        "stop by {subject}",
        "{subject}, please",
    ),
)

#: A third set, for selecting settings (thresholds, sizes) on unseen wording: no word or
#: shape of :data:`HELD_OUT` or :data:`TRAINING` (tests/envs/test_paraphrase.py checks it).
VALIDATION = Vocabulary(
    synonyms={
        "chair": ("rocker", "highchair"),
        "sofa": ("divan", "chesterfield"),
        "bed": ("futon", "bedstead"),
        "toilet": ("privy", "lav"),
        "tv_monitor": ("flatscreen", "widescreen"),
        "plant": ("shrub", "bonsai"),
        "table": ("counter", "trestle"),
        "cabinet": ("closet", "chest"),
    },
    room_words={"living_room": "sitting room", "hallway": "hall", "office": "den"},
    near_words=("bordering", "up against", "a step from"),
    color_subject="the {color} {noun}",
    room_shapes=(
        "check the {room} for {subject}",
        "enter the {room}; approach {subject}",
        "once you reach the {room}, seek out {subject}",
    ),
    plain_shapes=(
        "approach {subject}",
        "reach {subject}",
        "drive up to {subject}",
    ),
)

#: A second held-out set, written after failures on :data:`HELD_OUT` had been read and before
#: any change was measured on it: no word or shape of the other three sets.
SECOND_HELD_OUT = Vocabulary(
    synonyms={
        "chair": ("deckchair", "swivel chair"),
        "sofa": ("davenport", "sofa bed"),
        "bed": ("berth", "crib"),
        "toilet": ("john", "potty"),
        "tv_monitor": ("monitor", "boob tube"),
        "plant": ("cactus", "ficus"),
        "table": ("nightstand", "workbench"),
        "cabinet": ("armoire", "locker"),
    },
    room_words={"living_room": "front room", "hallway": "entryway", "office": "library"},
    near_words=("not far off", "in the vicinity of", "neighbouring"),
    color_subject="the {noun}, the {color} one",
    room_shapes=(
        "proceed to the {room} to spot {subject}",
        "{subject} should be in the {room}; get to it",
        "wander around the {room} until you spot {subject}",
    ),
    plain_shapes=(
        "get me to {subject}",
        "travel to {subject}",
        "my goal is {subject}",
    ),
)

#: A third held-out set, written after the second one's failures had been read and before any
#: change was measured on it: no word or shape of the other four sets.
THIRD_HELD_OUT = Vocabulary(
    synonyms={
        "chair": ("wingback", "beanbag"),
        "sofa": ("camelback", "settle"),
        "bed": ("waterbed", "four-poster"),
        "toilet": ("latrine", "restroom"),
        "tv_monitor": ("idiot box", "plasma"),
        "plant": ("succulent", "yucca"),
        "table": ("console", "dinette"),
        "cabinet": ("hutch", "credenza"),
    },
    room_words={"living_room": "drawing room", "hallway": "foyer", "office": "workspace"},
    near_words=("flanking", "abutting", "touching"),
    color_subject="the {noun} painted {color}",
    room_shapes=(
        "within the {room}, track down {subject}",
        "visit the {room}: {subject} awaits",
        "hunt through the {room} for {subject}",
    ),
    plain_shapes=(
        "track down {subject}",
        "hunt for {subject}",
        "{subject} is what i'm after",
    ),
)

#: A fourth held-out set, written after the third one's failures had been read and before any
#: change was measured on it: no word or shape of the other five sets.
FOURTH_HELD_OUT = Vocabulary(
    synonyms={
        "chair": ("lounger", "fauteuil"),
        "sofa": ("chaise longue", "sleeper"),
        "bed": ("trundle", "cradle"),
        "toilet": ("washroom", "bog"),
        "tv_monitor": ("tv set", "flat panel"),
        "plant": ("orchid", "potted palm"),
        "table": ("coffee table", "escritoire"),
        "cabinet": ("tallboy", "bookcase"),
    },
    room_words={"living_room": "parlour", "hallway": "vestibule", "office": "studio"},
    near_words=("hugging", "keeping company with", "tucked in with"),
    color_subject="the {noun} in {color}",
    room_shapes=(
        "explore the {room} till you discover {subject}",
        "{subject} lives somewhere in the {room}",
        "scout the {room} for {subject}",
    ),
    plain_shapes=(
        "steer toward {subject}",
        "kindly guide me to {subject}",
        "bring us over to {subject}",
    ),
)

#: A fifth held-out set, written after the fourth one's failures had been read and before any
#: change was measured on it: no word or shape of the other six sets.
FIFTH_HELD_OUT = Vocabulary(
    synonyms={
        "chair": ("barstool", "ladderback"),
        "sofa": ("three-seater", "canape"),
        "bed": ("bunkbed", "kingsize"),
        "toilet": ("throne", "outhouse"),
        "tv_monitor": ("gogglebox", "lcd"),
        "plant": ("monstera", "peace lily"),
        "table": ("bureau", "drop-leaf"),
        "cabinet": ("chiffonier", "curio"),
    },
    room_words={"living_room": "great room", "hallway": "landing", "office": "computer room"},
    near_words=("elbowing", "huddled round", "nuzzling"),
    color_subject="the {noun} whose colour is {color}",
    room_shapes=(
        "our destination is the {room}, {subject} specifically",
        "swing past the {room} - we want {subject}",
        "roll over to the {room}, halt at {subject}",
    ),
    plain_shapes=(
        "i'd like to stand at {subject}",
        "beeline for {subject}",
        "{subject}, pronto",
    ),
)

#: A sixth held-out set, written after the fifth one's failures had been read and before any
#: change was measured on it: no word or shape of the other seven sets.
SIXTH_HELD_OUT = Vocabulary(
    synonyms={
        "chair": ("footstool", "bench"),
        "sofa": ("sofabed", "banquette"),
        "bed": ("hammock", "bassinet"),
        "toilet": ("toilet bowl", "dunny"),
        "tv_monitor": ("crt", "vdu"),
        "plant": ("rubber plant", "aspidistra"),
        "table": ("gateleg", "kitchen island"),
        "cabinet": ("filing cabinet", "highboy"),
    },
    room_words={"living_room": "rumpus room", "hallway": "lobby", "office": "home office"},
    near_words=("facing", "opposite", "skirting"),
    color_subject="the {noun}, which is {color}",
    room_shapes=(
        "nip to the {room} to eyeball {subject}",
        "{subject} is over in the {room}; hurry along",
        "poke about the {room} for {subject}",
    ),
    plain_shapes=(
        "park yourself near {subject}",
        "show me {subject}",
        "wheel over to {subject}",
    ),
)

#: The vocabularies by name (``bench_robustness.py --vocabulary``).
VOCABULARIES: dict[str, Vocabulary] = {
    "held_out": HELD_OUT,
    "training": TRAINING,
    "validation": VALIDATION,
    "second_held_out": SECOND_HELD_OUT,
    "third_held_out": THIRD_HELD_OUT,
    "fourth_held_out": FOURTH_HELD_OUT,
    "fifth_held_out": FIFTH_HELD_OUT,
    "sixth_held_out": SIXTH_HELD_OUT,
}

#: Category -> words for it that the templates never use (the held-out set).
SYNONYMS: dict[str, tuple[str, ...]] = HELD_OUT.synonyms


def _room(room: str, rng: np.random.Generator, vocabulary: Vocabulary) -> str:
    word = room.replace("_", " ")
    return vocabulary.room_words.get(room, word) if rng.random() < 0.5 else word


def paraphrase(
    instruction: str, rng: np.random.Generator, vocabulary: Vocabulary = HELD_OUT
) -> str:
    """A paraphrase of ``instruction`` (a template instruction) that names the same goal,
    in the words of ``vocabulary``.

    Raises ``ValueError`` when the instruction names no known category.
    """
    parts = parse_instruction(instruction)
    category = parts["category"]
    if category is None:
        raise ValueError(f"instruction {instruction!r} names no known category")
    words = vocabulary.synonyms
    noun = str(rng.choice(words[category]))
    color, room, near = parts["color"], parts["room"], parts["near"]
    subject = vocabulary.color_subject.format(noun=noun, color=color) if color else f"the {noun}"
    if near:
        subject += f" {rng.choice(vocabulary.near_words)} the {rng.choice(words[near])}"
    if room:
        rooms = [_room(room, rng, vocabulary) for _ in vocabulary.room_shapes]
        shapes = [s.format(room=r, subject=subject) for s, r in zip(vocabulary.room_shapes, rooms)]
    else:
        shapes = [s.format(subject=subject) for s in vocabulary.plain_shapes]
    return str(rng.choice(shapes))


def paraphrase_instructions(
    instructions: Sequence[str], probability: float, vocabulary: Vocabulary = TRAINING
) -> list[str]:
    """Rewrite each instruction with ``probability`` (training augmentation).

    The draws come from torch's global RNG, so a training run that restores it resumes with
    the same rewrites. An instruction that names no known category is kept as it is.
    """
    import torch  # only here: the world reads the vocabularies without loading torch

    n = len(instructions)
    rewrite = (torch.rand(n) < probability).tolist()  # (n,)
    seeds = torch.randint(0, 2**31 - 1, (n,)).tolist()  # (n,)
    out = []
    for text, chosen, seed in zip(instructions, rewrite, seeds):
        if chosen and parse_instruction(text)["category"] is not None:
            text = paraphrase(text, np.random.default_rng(seed), vocabulary)
        out.append(text)
    return out


def paraphrase_episodes(
    specs: Sequence[EpisodeSpec], seed: int = 0, vocabulary: Vocabulary = HELD_OUT
) -> list[EpisodeSpec]:
    """The same episodes with instructions paraphrased in ``vocabulary`` (deterministic for a
    ``seed``)."""
    rng = np.random.default_rng(seed)
    return [
        dataclasses.replace(s, instruction=paraphrase(s.instruction, rng, vocabulary))
        for s in specs
    ]
