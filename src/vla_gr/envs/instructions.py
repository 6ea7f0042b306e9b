"""Language instructions that name a goal object uniquely among its distractors.

A goal is described by its category plus one or more attributes: colour, room type, or a
spatial relation ("next to the tv": another category within ``NEAR_DISTANCE`` in the same
room). A description is *unique* when no other object of the goal's category matches it;
``describe_goal`` only ever emits unique descriptions, in one of many phrasings.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from vla_gr.envs.placement import rects_overlap
from vla_gr.envs.scene import (
    CATEGORIES,
    COLORS,
    GOAL_CATEGORIES,
    ROOM_TYPES,
    House,
    ObjectInstance,
    category_display_name,
    room_display_name,
)

#: Footprint-to-footprint gap (m) under which two pieces in one room are "next to" each other.
NEAR_DISTANCE = 0.8

TEMPLATES: tuple[str, ...] = (
    "find the {np}",
    "go to the {np}",
    "navigate to the {np}",
    "walk to the {np}",
    "can you go to the {np}?",
    "please find the {np}",
    "head over to the {np}",
    "take me to the {np}",
    "locate the {np}",
    "i'm looking for the {np}",
    "could you bring me to the {np}?",
    "move to the {np}",
)
RELATION_WORDS: tuple[str, ...] = ("next to", "near", "beside", "by")


@dataclass(frozen=True)
class Description:
    """What an instruction says about its goal; None fields are not mentioned."""

    category: str
    color: str | None = None
    room: str | None = None  # room type
    near: str | None = None  # category of a neighbouring piece

    @property
    def intent(self) -> str:
        """Which attributes it uses, e.g. 'color+room'."""
        parts = [k for k in ("color", "room", "near") if getattr(self, k) is not None]
        return "+".join(parts)


def polygon_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance between convex polygons ``a`` (N, 2) and ``b`` (M, 2); 0 if they meet."""
    if len(a) == 4 and len(b) == 4 and rects_overlap(a, b):
        return 0.0

    def point_segment(p: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> float:
        d = s1 - s0
        t = float(np.clip(np.dot(p - s0, d) / max(float(np.dot(d, d)), 1e-12), 0.0, 1.0))
        return float(np.hypot(*(p - (s0 + t * d))))

    best = np.inf
    for p_set, q_set in ((a, b), (b, a)):
        for p in p_set:
            for k in range(len(q_set)):
                best = min(best, point_segment(p, q_set[k], q_set[(k + 1) % len(q_set)]))
    return float(best)


def neighbours(house: House, obj: ObjectInstance) -> list[ObjectInstance]:
    """Pieces of other categories in obj's room within ``NEAR_DISTANCE`` of its footprint."""
    fp = obj.footprint()
    reach = np.hypot(*obj.half_extents) + NEAR_DISTANCE
    out = []
    for other in house.objects:
        if other.category == obj.category or other.room_index != obj.room_index:
            continue
        if np.hypot(other.x - obj.x, other.y - obj.y) > reach + np.hypot(*other.half_extents):
            continue  # too far for any part of the footprints to come close
        if polygon_gap(fp, other.footprint()) <= NEAR_DISTANCE:
            out.append(other)
    return out


def neighbour_categories(house: House, obj: ObjectInstance) -> set[str]:
    """Categories (other than obj's) of pieces in obj's room within ``NEAR_DISTANCE``."""
    return {other.category for other in neighbours(house, obj)}


def matches(
    house: House, obj: ObjectInstance, desc: Description, near: set[str] | None = None
) -> bool:
    """Whether ``obj`` fits every attribute of ``desc`` (``near``: its neighbour categories)."""
    if obj.category != desc.category:
        return False
    if desc.color is not None and obj.color != desc.color:
        return False
    if desc.room is not None and house.rooms[obj.room_index].room_type != desc.room:
        return False
    if desc.near is None:
        return True
    return desc.near in (neighbour_categories(house, obj) if near is None else near)


def unique_descriptions(house: House, instance_id: int) -> list[Description]:
    """Every description of the object that no other object of its category matches."""
    goal = house.object(instance_id)
    room = house.rooms[goal.room_index].room_type
    near = sorted(neighbour_categories(house, goal))
    candidates = [
        Description(goal.category, color=goal.color),
        Description(goal.category, room=room),
        Description(goal.category, color=goal.color, room=room),
    ]
    candidates += [Description(goal.category, near=n) for n in near]
    candidates += [Description(goal.category, color=goal.color, near=n) for n in near]
    rivals = [o for o in house.objects if o.category == goal.category and o is not goal]
    rival_near = [neighbour_categories(house, o) if near else set() for o in rivals]
    return [
        d
        for d in candidates
        if not any(matches(house, o, d, n) for o, n in zip(rivals, rival_near))
    ]


def distractors(house: House, instance_id: int) -> list[int]:
    """Ids of the other objects of the goal's category."""
    goal = house.object(instance_id)
    return [
        o.instance_id
        for o in house.objects
        if o.category == goal.category and o.instance_id != goal.instance_id
    ]


def goal_candidates(house: House) -> list[int]:
    """Goal-category objects with at least one distractor and a unique description."""
    return [
        o.instance_id
        for o in house.objects
        if o.category in GOAL_CATEGORIES
        and distractors(house, o.instance_id)
        and unique_descriptions(house, o.instance_id)
    ]


def noun_phrase(desc: Description, rng: np.random.Generator) -> str:
    """'red chair in the kitchen', 'sofa next to the tv', ... (without the article)."""
    words = [desc.color] if desc.color else []
    words.append(category_display_name(desc.category))
    if desc.room:
        words.append(f"in the {room_display_name(desc.room)}")
    if desc.near:
        relation = RELATION_WORDS[int(rng.integers(len(RELATION_WORDS)))]
        words.append(f"{relation} the {category_display_name(desc.near)}")
    return " ".join(words)


def render_instruction(desc: Description, rng: np.random.Generator) -> str:
    """One phrasing of ``desc``, drawn from ``TEMPLATES``."""
    template = TEMPLATES[int(rng.integers(len(TEMPLATES)))]
    text = template.format(np=noun_phrase(desc, rng))
    return text[0].upper() + text[1:]


def describe_goal(house: House, instance_id: int, rng: np.random.Generator) -> str:
    """A natural instruction that identifies object ``instance_id`` uniquely in ``house``.

    Raises:
        ValueError: if the object cannot be told apart from its distractors.
    """
    options = unique_descriptions(house, instance_id)
    if not options:
        raise ValueError(
            f"instance_id={instance_id} has no unique description in house {house.seed}"
        )
    intents = sorted({d.intent for d in options})
    intent = intents[int(rng.integers(len(intents)))]
    pool = [d for d in options if d.intent == intent]
    return render_instruction(pool[int(rng.integers(len(pool)))], rng)


_CATEGORY_NAMES = {category_display_name(c): c for c in CATEGORIES}
_ROOM_NAMES = {room_display_name(r): r for r in ROOM_TYPES}
_NAME_RE = "|".join(sorted(map(re.escape, _CATEGORY_NAMES), key=len, reverse=True))
_RELATION_RE = re.compile(
    r"\b(?:" + "|".join(RELATION_WORDS) + r") the (" + _NAME_RE + r")\b", re.IGNORECASE
)
_ROOM_RE = re.compile(r"\bin the (" + "|".join(map(re.escape, _ROOM_NAMES)) + r")\b", re.IGNORECASE)
_CATEGORY_RE = re.compile(r"\b(?:(" + "|".join(COLORS) + r") )?(" + _NAME_RE + r")\b")


def parse_instruction(text: str) -> dict[str, str | None]:
    """Recover {'category', 'color', 'room', 'near'} from an instruction (None if absent)."""
    if not isinstance(text, str):
        raise ValueError(f"text must be a str, got {type(text).__name__}")
    low = text.lower()
    out: dict[str, str | None] = {"category": None, "color": None, "room": None, "near": None}
    relation = _RELATION_RE.search(low)
    if relation:
        out["near"] = _CATEGORY_NAMES[relation.group(1)]
        low = (
            low[: relation.start()]
            + " " * (relation.end() - relation.start())
            + low[relation.end() :]
        )
    room = _ROOM_RE.search(low)
    if room:
        out["room"] = _ROOM_NAMES[room.group(1)]
        low = low[: room.start()] + " " * (room.end() - room.start()) + low[room.end() :]
    goal = _CATEGORY_RE.search(low)
    if goal:
        out["color"] = goal.group(1)
        out["category"] = _CATEGORY_NAMES[goal.group(2)]
    return out
