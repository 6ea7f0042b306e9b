"""Say an instruction in the agent's own words: nouns mapped to the nearest known name.

The goal head, and S2's checks, learned the words of the templates ("sofa", "tv", "living
room"). Other words for the same things ("couch", "television", "lounge") reach the goal head
as an unfamiliar sentence and leave the checks' fields empty. :class:`InstructionLexicon`
reads the nouns of an instruction and maps each one to the category or room type whose name
the frozen sentence encoder places nearest (cosine similarity of the word's embedding and the
name's), then says the instruction again in the template phrasing:

    "go into the lounge and find the couch close to the houseplant"
    -> "find the sofa next to the plant"       (lounge: too far from every room name)

No word list is learned or stored: the encoder's own sense of which words are alike does
the mapping, so a word never seen in training can still find its name. What counts as a noun
is the first word after an article (the, a, an) that is not a colour word. Nouns are read in
order: a room type when the word is at least ``room_threshold`` similar to a room name and
nearer to it than to any category, otherwise the goal (the first) or a relation's anchor
(the second) when the nearest category leads the runner-up by ``category_margin``; a noun
that does not is kept as it was said. With ``word_senses`` a noun is first looked up in
WordNet (:class:`~vla_gr.agent.perception.word_senses.WordSenses`): what its most common physical
sense is a kind of names its category or room type, a place of no known type ("the house")
and a word for no physical thing ("a step from") are neither goal, anchor nor room, and only
a word WordNet lacks, or knows as some other object, goes to the encoder; a two-word noun
WordNet knows ("sofa bed", "swivel chair") is read whole. With
``locative_senses`` too, a noun after a preposition of containment ("in", "into", "inside",
"within", "throughout") is read by its most common sense that is a room or building, when it
has one: "go into the lounge" names a room, though WordNet's first "lounge" is a sofa. With
``place_senses``, a room WordNet gives no type ("foyer") is the room type whose name the
encoder puts nearest, when it leads the next by ``room_margin``; a word WordNet knows as some
other thing ("corridor": a passageway) names a room as it would without word senses; and a
noun after a preposition of containment that WordNet does not know as a category is where to
look, never the goal ("within the workspace, track down the couch"). With
``clause_places``, a first noun that can be a room or building and is followed by a noun in
another clause (after a comma, semicolon, colon or dash, or "and", "then", "until", ...) is
read as after "into the": a goal and its relation's anchor are said in one clause, so "head
for the lounge, then look for the seat" names no sofa next to a chair. With ``noun_heads``, a
word between the article and the noun that says which or what kind
(:meth:`~vla_gr.agent.perception.word_senses.WordSenses.modifies`: "the great room", "the filing
cabinet") is passed over like a colour, and a room of no known type is read by the encoder
with it ("great room"). An instruction in
which the template readers already find what the lexicon reads comes out unchanged, so
template instructions reach the agent exactly as before.

``model.instruction_lexicon`` has no weights: its settings are inference settings
(``vla-gr export``), chosen on the validation paraphrase vocabulary.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from vla_gr.agent.perception.instruction_reader import read_instruction
from vla_gr.agent.perception.object_category import CATEGORIES, spoken_name
from vla_gr.agent.perception.room_type import ROOM_TYPES, spoken_room_name
from vla_gr.agent.perception.word_senses import WordSenses
from vla_gr.core.encoders.text import load_sentence_model

__all__ = ["InstructionLexicon", "InstructionLexiconConfig", "LexiconReading"]

_ARTICLES = frozenset({"the", "a", "an"})
_LOCATIVE = frozenset({"in", "into", "inside", "within", "throughout"})  # "... the <place>"
_WORD = re.compile(r"[a-z]+(?:'[a-z]+)?")
# what ends a clause: punctuation between two words (not a hyphen inside one), or a conjunction
_CLAUSE_MARK = re.compile(r"[,;:!?.\u2013\u2014]|\s-\s")
_CONJUNCTIONS = frozenset({"and", "then", "until", "till", "before", "after", "once", "while"})


def _words_and_clauses(text: str) -> tuple[list[str], list[int]]:
    """The words of lower-case ``text`` and the index of the clause each one is in."""
    words: list[str] = []
    clauses: list[int] = []
    clause, end = 0, 0
    for match in _WORD.finditer(text):
        word = match.group()
        if words and (_CLAUSE_MARK.search(text[end : match.start()]) or word in _CONJUNCTIONS):
            clause += 1
        words.append(word)
        clauses.append(clause)
        end = match.end()
    return words, clauses


@dataclass
class InstructionLexiconConfig:
    """The instruction lexicon (``model.instruction_lexicon.*``); no weights.

    ``categories`` and ``room_types`` follow ``model.object_category.categories`` and
    ``model.room_type.room_types``.
    """

    enabled: bool = False  # say non-template instructions in template words before S2 reads them
    # look nouns up in WordNet first (what a word is a kind of); the encoder for the rest
    word_senses: bool = False
    # with word_senses: a noun after "in / into / inside / within / throughout the" is read by
    # its most common sense that is a room or building, when it has one
    locative_senses: bool = False
    # with word_senses: a place WordNet gives no known type ("the foyer") is the room type
    # whose name the encoder puts nearest, by room_margin; a word WordNet knows as some other
    # thing ("corridor": a passageway) can still name a room by room_threshold, as without
    # word senses; with locative_senses too, a noun after "in / into / ... the" that WordNet
    # does not know as a category is where to look, never the goal or an anchor
    place_senses: bool = False
    # with locative_senses: a first noun that can be a room or building, followed by a noun
    # in another clause (after "," ";" ":" a dash, or "and", "then", "until", ...), is read as
    # where to look: a goal and its relation's anchor share a clause ("head for the lounge,
    # then look for the seat": the lounge is a room, the seat the goal)
    clause_places: bool = False
    # with word_senses: a word before a noun that is mostly an adjective, or that names no
    # category or room while the noun does, says which or what kind: the noun after it is read
    # ("the great room", "the filing cabinet", "the corner sofa")
    noun_heads: bool = False
    room_margin: float = 0.05  # lead of the nearest room name over the next one for a place
    room_threshold: float = 0.6  # cosine similarity at which a noun can name a room type
    category_margin: float = 0.05  # lead of the nearest category over the next one to name it
    colors: list[str] = field(
        default_factory=lambda: [
            "red", "blue", "green", "yellow", "white", "black", "orange", "purple",
        ]
    )  # fmt: skip
    categories: list[str] = field(default_factory=lambda: list(CATEGORIES))
    room_types: list[str] = field(default_factory=lambda: list(ROOM_TYPES))

    def __post_init__(self) -> None:
        if not -1.0 <= self.room_threshold <= 1.0:
            raise ValueError(
                f"model.instruction_lexicon.room_threshold={self.room_threshold} must be in "
                "[-1, 1] (a cosine similarity)"
            )
        if not 0.0 <= self.room_margin <= 2.0:
            raise ValueError(
                f"model.instruction_lexicon.room_margin={self.room_margin} must be in [0, 2]"
            )
        if not 0.0 <= self.category_margin <= 2.0:
            raise ValueError(
                f"model.instruction_lexicon.category_margin={self.category_margin} must be in "
                "[0, 2]"
            )


@dataclass(frozen=True)
class LexiconReading:
    """What the lexicon took an instruction to say. ``category`` / ``anchor`` / ``room`` are
    names from the config (None: not said or not recognised); ``goal_word`` / ``anchor_word``
    are the nouns as said (None without one)."""

    category: str | None = None
    color: str | None = None
    room: str | None = None
    anchor: str | None = None
    goal_word: str | None = None
    anchor_word: str | None = None
    room_word: str | None = None


def _nearest_by_lead(similarities: torch.Tensor, margin: float) -> int | None:
    """Index of the largest of ``similarities`` (N,) when it leads the next by ``margin``."""
    top = similarities.topk(min(2, len(similarities)))
    lead = float(top.values[0] - top.values[1]) if len(top.values) > 1 else 2.0
    return int(top.indices[0]) if lead >= margin else None


class InstructionLexicon:
    """Maps an instruction's nouns to the config's category and room-type names and renders
    the template phrasing (:meth:`canonical`); results are cached per instruction."""

    def __init__(
        self, config: InstructionLexiconConfig | None = None, model_path=None, encoder=None
    ) -> None:
        """``encoder`` (anything with ``encode(texts) -> (N, E)``) replaces the frozen sentence
        model in folder ``model_path`` (MiniLM's by default)."""
        self.config = c = config or InstructionLexiconConfig()
        self._encoder = encoder if encoder is not None else load_sentence_model(model_path)
        self._category_names = [spoken_name(k) for k in c.categories]
        self._room_names = [spoken_room_name(r) for r in c.room_types]
        self._categories = self._embed(self._category_names)  # (K, E)
        self._rooms = self._embed(self._room_names)  # (R, E)
        self._words: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        self._senses = None  # loaded now, so that no control step waits for WordNet
        if c.word_senses:
            self._senses = WordSenses(self._category_names, self._room_names).load()
        self._canonical: dict[str, str] = {}

    def _embed(self, texts: Sequence[str]) -> torch.Tensor:
        return F.normalize(self._encoder.encode(list(texts)).float(), dim=-1)  # (N, E)

    def similarities(self, word: str) -> tuple[torch.Tensor, torch.Tensor]:
        """Cosine similarity of ``word`` to each category name (K,) and room name (R,)."""
        if word not in self._words:
            e = self._embed([word])[0]  # (E,)
            self._words[word] = (self._categories @ e, self._rooms @ e)  # (K,), (R,)
        return self._words[word]

    def _room_of(self, words: list[str], i: int) -> tuple[str | None, int]:
        """(room type named by the noun at ``words[i]`` or its two-word phrase, words used)."""
        if words[i] in self._category_names:
            return None, 1  # a category's own name is no room
        for span in (2, 1):
            phrase = " ".join(words[i : i + span])
            if i + span <= len(words) and phrase in self._room_names:
                return self.config.room_types[self._room_names.index(phrase)], span
        best: tuple[float, int, int] = (-2.0, 0, 1)  # (similarity, room index, span)
        for span in (1, 2):
            if i + span > len(words):
                break
            near = self._room_like(" ".join(words[i : i + span]))
            if near is not None and near[0] > best[0]:
                best = (*near, span)
        if best[0] >= self.config.room_threshold:
            return self.config.room_types[best[1]], best[2]
        return None, 1

    def _room_like(self, phrase: str) -> tuple[float, int] | None:
        """(similarity, index) of the room name nearest ``phrase`` when it is nearer to it than
        to every category name, else None."""
        to_categories, to_rooms = self.similarities(phrase)
        score, room = to_rooms.max(dim=0)
        return (float(score), int(room)) if float(score) > float(to_categories.max()) else None

    def _room_by_encoder(self, phrase: str, kind: str) -> str | None:
        """The room type a noun WordNet does not type names by the encoder (``place_senses``):
        a room of no known type (``kind`` "room") the nearest room name by ``room_margin``; a
        building none; another word one at least ``room_threshold`` similar and nearer than
        every category; else None."""
        if kind == "place":
            return None
        if kind == "room":
            room = _nearest_by_lead(self.similarities(phrase)[1], self.config.room_margin)
        else:
            near = self._room_like(phrase)
            room = near[1] if near is not None and near[0] >= self.config.room_threshold else None
        return None if room is None else self.config.room_types[room]

    def _category_of(self, word: str) -> str | None:
        """The category ``word`` names: its own name, or the nearest one by ``category_margin``."""
        if word in self._category_names:
            return self.config.categories[self._category_names.index(word)]
        k = _nearest_by_lead(self.similarities(word)[0], self.config.category_margin)
        return None if k is None else self.config.categories[k]

    def _modifies(self, words: list[str], i: int) -> bool:
        """Whether ``words[i]`` is said before a later noun to say which or what kind
        (``noun_heads``: "the great room", "the big old armchair"); the noun is read."""
        if not (self.config.noun_heads and self._senses is not None):
            return False
        colors, senses = self.config.colors, self._senses
        head = i + 1  # the noun: past colours and the modifiers after words[i] ("big old red")
        while head + 1 < len(words) and (
            words[head] in colors
            or (words[head + 1] not in colors and senses.modifies(words[head], words[head + 1]))
        ):
            head += 1  # a colour is never the noun ("the succulent painted orange")
        if head >= len(words) or words[head] in colors:
            return False
        return senses.modifies(words[i], words[head])

    def _role(
        self, words: list[str], i: int, locative: bool, modifiers: Sequence[str] = ()
    ) -> tuple[str, str | None, int]:
        """(kind, name, words used) of the noun at ``words[i]``: kind "room" / "category"
        (name from the config, or None for a noun kept as said) / "skip" (a place of no known
        type, or no physical thing: neither goal, anchor nor room). ``locative``: the noun
        follows a preposition of containment; ``modifiers``: the words said before it, which
        the encoder reads with a room of no known type ("the great room")."""
        c = self.config
        if self._senses is not None:
            place = locative and c.locative_senses
            for span in (2, 1):
                if i + span > len(words):
                    continue
                phrase = " ".join(words[i : i + span])
                role = self._senses.role(phrase, place)
                if role is None or (span == 2 and role[0] not in ("room", "place", "category")):
                    continue
                kind, index = role
                if kind == "room" and index is not None:
                    return "room", c.room_types[index], span
                if kind == "category":
                    return "category", c.categories[index], span
                said = " ".join([*modifiers, phrase])
                room = self._room_by_encoder(said, kind) if c.place_senses else None
                if room is not None:
                    return "room", room, span
                if kind == "object" and not (place and c.place_senses):
                    return "category", self._category_of(words[i]), span  # the encoder may
                return "skip", None, span  # after "in the": where to look, not what
        named_room, used = self._room_of(words, i)
        if named_room is not None:
            return "room", named_room, used
        return "category", self._category_of(words[i]), used

    def _can_be_a_place(self, words: list[str], i: int) -> bool:
        """Whether the noun at ``words[i]`` (or its two-word phrase) has a sense that is a
        room or building (``clause_places``, with word and locative senses)."""
        c = self.config
        if not (c.clause_places and c.locative_senses and self._senses is not None):
            return False
        phrases = (" ".join(words[i : i + span]) for span in (2, 1) if i + span <= len(words))
        return any(
            (role := self._senses.role(p, place=True)) is not None and role[0] in ("room", "place")
            for p in phrases
        )

    def read(self, instruction: str) -> LexiconReading:
        """The goal noun, its colour, room and relation anchor as the config names them."""
        if not isinstance(instruction, str):
            raise TypeError(f"instruction must be a str, got {type(instruction).__name__}")
        words, clauses = _words_and_clauses(instruction.lower())
        articles = [j for j, w in enumerate(words) if w in _ARTICLES]
        colors = [w for w in words if w in self.config.colors]
        nouns: list[tuple[str, str | None]] = []  # (word as said, category or None)
        room = room_word = None
        i = 0
        while i < len(words):
            if words[i] not in _ARTICLES:
                i += 1
                continue
            locative = i > 0 and words[i - 1] in _LOCATIVE
            later_clause = any(clauses[j] != clauses[i] for j in articles if j > i)
            i += 1
            said_from = i  # where the noun phrase starts, colours and modifiers included
            while i < len(words) and (words[i] in self.config.colors or self._modifies(words, i)):
                i += 1
            if i >= len(words):
                break
            if not (locative or nouns) and later_clause and self._can_be_a_place(words, i):
                locative = True  # a goal and its anchor share a clause: this is where to look
            modifiers = [w for w in words[said_from:i] if w not in self.config.colors]
            kind, name, used = self._role(words, i, locative, modifiers)
            if kind == "room" and room is None:
                room, room_word = name, " ".join(modifiers + words[i : i + used])
            elif kind == "category" and len(nouns) < 2:
                nouns.append((words[i], name))
            i += used
        goal = nouns[0] if nouns else (None, None)
        anchor = nouns[1] if len(nouns) > 1 else (None, None)
        return LexiconReading(
            category=goal[1],
            color=colors[0] if colors else None,
            room=room,
            anchor=anchor[1],
            goal_word=goal[0],
            anchor_word=anchor[0],
            room_word=room_word,
        )

    def render(self, reading: LexiconReading) -> str | None:
        """The template phrasing of ``reading`` (unrecognised nouns as said), or None without
        a goal noun."""
        if reading.goal_word is None:
            return None
        goal = reading.goal_word if reading.category is None else spoken_name(reading.category)
        words = ["find the"] + ([reading.color] if reading.color else []) + [goal]
        if reading.room is not None:
            words.append(f"in the {spoken_room_name(reading.room)}")
        if reading.anchor_word is not None:
            anchor = reading.anchor_word if reading.anchor is None else spoken_name(reading.anchor)
            words.append(f"next to the {anchor}")
        return " ".join(words)

    def canonical(self, instruction: str) -> str:
        """``instruction`` in template words; unchanged when the template readers
        (:func:`~vla_gr.agent.perception.read_instruction` without a learned reader) already
        find in it what the lexicon reads, or when it has no goal noun."""
        if instruction not in self._canonical:
            reading = self.read(instruction)
            rendered = self.render(reading)
            template = read_instruction(instruction, self.config.categories, self.config.room_types)
            if rendered is None or (
                (template.category, template.anchor, template.room) == self._indices(reading)
            ):
                rendered = instruction
            self._canonical[instruction] = rendered
        return self._canonical[instruction]

    def _indices(self, reading: LexiconReading) -> tuple[int | None, ...]:
        """``reading`` as the template readers index it (categories 1-based, rooms 0-based)."""
        c = self.config
        category, anchor, room = reading.category, reading.anchor, reading.room
        return (
            None if category is None else c.categories.index(category) + 1,
            None if anchor is None else c.categories.index(anchor) + 1,
            None if room is None else c.room_types.index(room),
        )
