"""The world's own reading of a request: which object of the house a text describes.

``reset(options={"instruction": text})`` grounds the user's words with it (the goal becomes the
object they describe), and :func:`~vla_gr.envs.episodes.load_episodes` checks with it that a
file's instruction describes its goal. It knows the generator's words (categories, colours,
rooms, relation words), the everyday words of :data:`SYNONYMS`, :data:`ROOM_SYNONYMS` and
:data:`RELATION_PHRASES`, and the words of every paraphrase vocabulary; it is the world's, not
an agent's reader.

A request names one goal (the first object that no relation word introduces), and may give its
colour, its room and one neighbour ("next to the tv", "by the red table"). The goal is the one
object of the house that fits all of it; no object or several is a one-line ``ValueError``
naming what the house has.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from vla_gr.envs.instructions import RELATION_WORDS, Description, matches, neighbours
from vla_gr.envs.paraphrase import VOCABULARIES
from vla_gr.envs.scene import (
    CATEGORIES,
    COLORS,
    ROOM_TYPES,
    House,
    ObjectInstance,
    category_display_name,
    room_display_name,
)
from vla_gr.text_fold import fold_to_ascii

__all__ = [
    "RELATION_PHRASES",
    "ROOM_SYNONYMS",
    "SYNONYMS",
    "Grounding",
    "Request",
    "fits",
    "ground",
    "object_phrase",
    "read_request",
]

#: Everyday words for the categories, beyond the generator's names and the paraphrase sets.
SYNONYMS: dict[str, str] = {
    "couch": "sofa",
    "settee": "sofa",
    "loveseat": "sofa",
    "telly": "tv_monitor",
    "television": "tv_monitor",
    "tv monitor": "tv_monitor",
    "armchair": "chair",
    "seat": "chair",
    "stool": "chair",
    "loo": "toilet",
    "wc": "toilet",
    "lavatory": "toilet",
    "houseplant": "plant",
    "house plant": "plant",
    "potted plant": "plant",
    "pot plant": "plant",
    "flowerpot": "plant",
    "desk": "table",
    "dining table": "table",
    "cupboard": "cabinet",
    "dresser": "cabinet",
    "wardrobe": "cabinet",
    "chest of drawers": "cabinet",
}
#: Everyday words for the room types, beyond the generator's names and the paraphrase sets.
ROOM_SYNONYMS: dict[str, str] = {
    "lounge": "living_room",
    "sitting room": "living_room",
    "living area": "living_room",
    "corridor": "hallway",
    "hall": "hallway",
    "study": "office",
    "kitchenette": "kitchen",
    "bath room": "bathroom",
    "bed room": "bedroom",
}
#: Words that say "next to", beyond the generator's and the paraphrase sets'.
RELATION_PHRASES: tuple[str, ...] = ("close to", "near to", "nearby", "right next to", "beside")
#: Colours no object of the world has: a request naming one fits nothing (it is not ignored).
OTHER_COLOURS: tuple[str, ...] = (
    "pink", "brown", "grey", "gray", "beige", "silver", "gold", "golden", "cyan", "turquoise",
    "navy", "maroon", "cream", "violet", "magenta", "lilac", "lavender",
)  # fmt: skip
_ARTICLES = frozenset({"the", "a", "an", "that", "this", "some", "any", "one"})
_NEGATION = re.compile(
    r"\b(?:not|never|except|without|nor|other than|anything but|instead of|rather than|"
    r"apart from)\b|n't\b"
)


def _words(text: str) -> str:
    """Lower-case ASCII words separated by single spaces (hyphens and punctuation are spaces)."""
    return " ".join(re.sub(r"[^a-z0-9']+", " ", fold_to_ascii(text).lower()).split())


def _table(*sources: dict[str, str]) -> dict[str, str]:
    """One word -> name table from several; a word two sources send apart is a bug."""
    out: dict[str, str] = {}
    for source in sources:
        for word, name in source.items():
            word = _words(word)
            if out.setdefault(word, name) != name:
                raise ValueError(f"{word!r} means both {out[word]} and {name}")
    return out


_CATEGORY_WORDS = _table(
    {category_display_name(c): c for c in CATEGORIES},
    {c.replace("_", " "): c for c in CATEGORIES},
    SYNONYMS,
    *({w: c for c, words in v.synonyms.items() for w in words} for v in VOCABULARIES.values()),
)
_ROOM_WORDS = _table(
    {room_display_name(r): r for r in ROOM_TYPES},
    ROOM_SYNONYMS,
    *({w: r for r, w in v.room_words.items()} for v in VOCABULARIES.values()),
)
_RELATIONS = sorted(
    {_words(w) for w in (*RELATION_WORDS, *RELATION_PHRASES)}
    | {_words(w) for v in VOCABULARIES.values() for w in v.near_words},
    key=len,
    reverse=True,
)
_COLOURS = (*COLORS, *OTHER_COLOURS)


def _alternation(words) -> str:
    return "|".join(re.escape(w) for w in sorted(words, key=len, reverse=True))


_CATEGORY_RE = re.compile(rf"\b({_alternation(_CATEGORY_WORDS)})(?:s|es)?\b")
_ROOM_RE = re.compile(rf"\b({_alternation(_ROOM_WORDS)})s?\b")
_RELATION_RE = re.compile(rf"\b(?:{_alternation(_RELATIONS)})\b")
_COLOUR_RE = re.compile(rf"\b({_alternation(_COLOURS)})\b")


@dataclass(frozen=True)
class Request:
    """What a request says: the goal's category (None: it names no object we know), its
    colour and room, and a neighbour's category and colour (None where not said)."""

    category: str | None
    color: str | None = None
    room: str | None = None
    near: str | None = None
    near_color: str | None = None

    @property
    def fields(self) -> dict[str, str | None]:
        """The generator's fields of the goal (``episodes.DESCRIPTION_FIELDS``)."""
        return {"category": self.category, "color": self.color, "room": self.room,
                "near": self.near}  # fmt: skip


@dataclass(frozen=True)
class Grounding:
    """The object a request describes, and the request as read."""

    instance: ObjectInstance
    request: Request

    @property
    def fields(self) -> dict[str, str | None]:
        return self.request.fields


def _blank(text: str, spans) -> str:
    """``text`` with each (start, end) span replaced by spaces (positions stay)."""
    chars = list(text)
    for start, end in spans:
        chars[start:end] = " " * (end - start)
    return "".join(chars)


def _only_fillers(gap: str) -> bool:
    """Whether ``gap`` holds nothing but articles and colour words."""
    return all(w in _ARTICLES or w in _COLOURS for w in gap.split())


def read_request(text: str) -> Request:
    """What ``text`` says of its goal; ValueError (one line) when it names two objects without
    a relation, two rooms, two colours of one object, several neighbours or a negation."""
    said = _words(text)
    quoted = _quote(text)
    found = [(m.start(), m.end(), _CATEGORY_WORDS[m.group(1)]) for m in _CATEGORY_RE.finditer(said)]
    rest = _blank(said, [(s, e) for s, e, _ in found])
    rooms = [(m.start(), m.end(), _ROOM_WORDS[m.group(1)]) for m in _ROOM_RE.finditer(rest)]
    rest = _blank(rest, [(s, e) for s, e, _ in rooms])
    relations = [(m.start(), m.end()) for m in _RELATION_RE.finditer(rest)]
    rest = _blank(rest, relations)
    if _NEGATION.search(rest):
        raise ValueError(f"{quoted} says what not to find; name the object to find")
    if not found:
        return Request(None)

    def introduced(start: int) -> bool:  # a relation word just before it ("next to the")
        return any(e <= start and _only_fillers(said[e:start]) for _, e in relations)

    goal = next((i for i, (s, _, _) in enumerate(found) if not introduced(s)), 0)
    goal_start, goal_end, category = found[goal]
    roles = {goal: "goal"}
    for i, (start, _, name) in enumerate(found):
        if i == goal:
            continue
        if name == category and not introduced(start):
            roles[i] = "goal"  # the goal said again ("the chair, the red chair")
        elif introduced(start) or any(goal_end <= s and e <= start for s, e in relations):
            roles[i] = "near"
        else:
            raise ValueError(
                f"{quoted} names two objects ({_name(category)}, {_name(name)}); ask for one, "
                "or say which one it stands next to"
            )
    near = sorted({found[i][2] for i, role in roles.items() if role == "near"})
    if len(near) > 1:
        raise ValueError(
            f"{quoted} names more than one neighbour ({', '.join(map(_name, near))}); "
            "say one thing the goal stands next to"
        )
    colours: dict[str, set[str]] = {"goal": set(), "near": set()}
    for m in _COLOUR_RE.finditer(rest):
        after = [i for i, (s, _, _) in enumerate(found) if s >= m.end()]
        before = [i for i, (_, e, _) in enumerate(found) if e <= m.start()]
        if after and _only_fillers(said[m.end() : found[after[0]][0]]):
            owner = after[0]  # an adjective: "the red chair"
        else:
            owner = before[-1] if before else after[0]  # "the chair that is red"
        colours[roles[owner]].add(m.group(1))
    for role, said_colours in colours.items():
        if len(said_colours) > 1:
            what = _name(category) if role == "goal" else _name(near[0])
            raise ValueError(
                f"{quoted} gives the {what} two colours ({', '.join(sorted(said_colours))})"
            )
    room_types = sorted({r for _, _, r in rooms})
    if len(room_types) > 1:
        raise ValueError(
            f"{quoted} names two rooms ({', '.join(map(room_display_name, room_types))}); say "
            f"which room the {_name(category)} is in"
        )
    return Request(
        category,
        color=next(iter(colours["goal"]), None),
        room=room_types[0] if room_types else None,
        near=near[0] if near else None,
        near_color=next(iter(colours["near"]), None),
    )


def fits(house: House, obj: ObjectInstance, request: Request) -> bool:
    """Whether ``obj`` fits everything ``request`` says."""
    description = Description(request.category, request.color, request.room, request.near)
    if not matches(house, obj, description):
        return False
    if request.near_color is None:
        return True
    return any(
        n.category == request.near and n.color == request.near_color for n in neighbours(house, obj)
    )


def ground(house: House, text: str) -> Grounding:
    """The one object of ``house`` that ``text`` describes; ValueError in one line naming what
    the house has when it describes none or several."""
    request = read_request(text)
    quoted = _quote(text)
    if request.category is None:
        names = sorted({_name(o.category) for o in house.objects})
        raise ValueError(f"{quoted} names no object; house {house.seed} has: {', '.join(names)}")
    chosen = [o for o in house.objects if fits(house, o, request)]
    if len(chosen) == 1:
        return Grounding(chosen[0], request)
    name = _name(request.category)
    same = [o for o in house.objects if o.category == request.category]
    if not same:
        names = sorted({_name(o.category) for o in house.objects})
        raise ValueError(
            f"{quoted} asks for a {name}; house {house.seed} has none (it has: {', '.join(names)})"
        )
    if not chosen:
        raise ValueError(
            f"{quoted} fits no object in house {house.seed}; its {name}s: {_listing(house, same)}"
        )
    raise ValueError(
        f"{quoted} fits {len(chosen)} objects in house {house.seed} ({_listing(house, chosen)}); "
        "say which by its colour, its room or what it stands next to"
    )


def _name(category: str) -> str:
    return category_display_name(category)


def _quote(text: str, limit: int = 80) -> str:
    folded = fold_to_ascii(text) if isinstance(text, str) else repr(text)
    return repr(folded if len(folded) <= limit else folded[: limit - 3] + "...")


def object_phrase(house: House, obj: ObjectInstance) -> str:
    """'red chair in the kitchen next to the table and the tv': what the world knows of it."""
    room = room_display_name(house.rooms[obj.room_index].room_type)
    near = sorted({_name(n.category) for n in neighbours(house, obj)})
    beside = f" next to the {' and the '.join(near)}" if near else ""
    return f"{obj.color} {_name(obj.category)} in the {room}{beside}"


def _listing(house: House, objects: list[ObjectInstance]) -> str:
    return ", ".join(object_phrase(house, o) for o in objects)
