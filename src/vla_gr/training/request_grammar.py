"""A generative grammar of requests, each word labelled with its role: what the tagger of the
instruction reader learns from.

A request names a goal object (a category word), perhaps its colour, its room and a
neighbour (the anchor), in far more shapes than the environment's templates: commands,
questions, wishes, the noun said first ("green plant by the desk - go there"), appositives
("the chair, the red one"), possessives ("the kitchen's chair"), room nouns as modifiers
("the bathroom plant"), relative clauses ("the sofa that is blue"), the room or the anchor said
first, context sentences around it ("I'm tired."), politeness, typing slips. It also says
what the reader must refuse: goals it cannot name (an object no category holds, a colour or
room no table holds), negations ("the chair that isn't red"), two goals (in a row, both
together, one a stop on the way to the other), and words that ask for nothing.

Words come from the reader's own tables (:mod:`vla_gr.agent.reading.vocabulary`): the class
names and the WordNet words for them, weighted towards the common ones, and WordNet's other
artefacts, colours and rooms for what no table holds. No request set written to measure the
reader is read here; its phrases (verbs, politeness, joins of two goals, ...) are data in
:mod:`vla_gr.training.request_phrases`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vla_gr.agent.reading.reader import display_name
from vla_gr.agent.reading.tagger import TAGS
from vla_gr.agent.reading.text import normalise_request, request_words
from vla_gr.agent.reading.vocabulary import COLOUR_WORDS, WordTable
from vla_gr.training.request_phrases import (
    AFTER,
    ANCHOR_FIRST,
    AND,
    BOTH,
    BOTH_AND,
    CHAT,
    CONTEXT,
    DEPTH_SHARE,
    DETERMINERS,
    DO_NOT,
    DOING,
    EACH,
    FRONTED_COMMANDS,
    GIBBERISH_LETTERS,
    KEEP_AWAY,
    NEAR,
    NEGATION_WORDS,
    NEGATIONS,
    OBJECT_CONTEXT,
    ON_THE_WAY,
    OTHER_PLACES,
    PLACE_PREP,
    POLITE_AFTER,
    POLITE_BEFORE,
    QUESTIONS,
    ROOM_PREP,
    SECOND,
    SIZE,
    VERBS,
    WISHES,
)

__all__ = ["LabelledRequest", "RequestGrammar"]


@dataclass(frozen=True)
class LabelledRequest:
    """A request, its words (as :func:`request_words` splits it), one tag per word, the
    fields it names (class names; None: not named) and, for a request the reader must not
    act on, why (``refuse``: "nothing", "unknown_object", "unknown_colour", "unknown_room",
    "unknown_anchor", "negation", "two_goals"; None: act on it)."""

    text: str
    words: tuple[str, ...]
    tags: tuple[str, ...]
    fields: dict = field(default_factory=dict)
    refuse: str | None = None


class RequestGrammar:
    """``sample(rng)`` -> one :class:`LabelledRequest`; ``batch(n, seed)`` -> n of them."""

    def __init__(self, table: WordTable, goal_categories, categories, rooms) -> None:
        self.goal_categories = list(goal_categories)
        self.categories = list(categories)
        self.rooms = list(rooms)
        self.nouns = self._words_by_class(table.objects, table)
        self.room_words = self._words_by_class(table.rooms, table)
        named = set(table.objects) | set(table.rooms)
        colour_words = {w for words in COLOUR_WORDS.values() for w in words}
        # what no table holds, and whose head names no class either ("olive green" is green)
        self.unknown_objects = sorted(
            w for w in self._wordnet_words("artifact.n.01", named, table)
            if table.name_in(w.split(), "category") is None
        )  # fmt: skip
        self.unknown_colours = sorted(
            w for w in self._wordnet_words("chromatic_color.n.01", named, table, colour_words)
            | self._wordnet_words("achromatic_color.n.01", named, table, colour_words)
            if table.name_in(w.split(), "colour") is None
        )  # fmt: skip
        self.unknown_rooms = sorted(
            w for root in OTHER_PLACES for w in self._wordnet_words(root, named, table)
            if table.name_in(w.split(), "room") is None
            and table.name_in(w.split(), "category") is None
        )  # fmt: skip
        self._other_places = frozenset(self.unknown_rooms)
        # the everyday ones (a root's own words and those one level below: "balcony",
        # "garage", "khaki"), said as often as all the rest
        generic = {w for root in ("room.n.01", "area.n.05", "floor.n.02")
                   for w in self._wordnet_words(root, named, table, max_depth=0)}  # fmt: skip
        self.common_places = sorted(
            w for root in OTHER_PLACES
            for w in self._wordnet_words(root, named, table, max_depth=1)
            if w in self._other_places and w not in generic
        )  # fmt: skip
        self.common_colours = sorted(
            w for root in ("chromatic_color.n.01", "achromatic_color.n.01")
            for w in self._wordnet_words(root, named, table, colour_words, max_depth=2)
            if w in self.unknown_colours
        )  # fmt: skip
        self.adjectives = sorted(  # adjectives and participles no table holds
            w for w in self._adjectives() if table.name_in([w], "colour") is None
            and table.name_in([w], "room") is None and table.name_in([w], "category") is None
        )  # fmt: skip
        self.fillers = sorted(
            w for w in table.known
            if w.isalpha() and 3 <= len(w) <= 9 and table.look_up([w], "colour") is None
        )  # fmt: skip
        # field words a typing slip may land on: those the reader repairs a slip of
        self._field_words = frozenset().union(*table.slip_targets.values())

    @staticmethod
    def _words_by_class(table: dict, words: WordTable) -> dict[str, list[tuple[str, float]]]:
        """{class: [(phrase, weight)]}: per class, the name half the time, then the WordNet
        words by how near the class's own senses they are (:data:`DEPTH_SHARE`)."""
        groups: dict[str, dict[int, list[str]]] = {}
        for phrase, name in table.items():
            if name.how == "joined":  # "livingroom": read, not said by the grammar
                continue
            text = " ".join(phrase)
            level = -1 if text == display_name(name.name) else (min(words._depth.get(phrase, 1), 3))
            groups.setdefault(name.name, {}).setdefault(level, []).append(text)
        out: dict[str, list[tuple[str, float]]] = {}
        for name, by_level in groups.items():
            total = sum(DEPTH_SHARE[level] for level in by_level)
            out[name] = [
                (text, DEPTH_SHARE[level] / total / len(texts))
                for level, texts in by_level.items()
                for text in texts
            ]
        return out

    @staticmethod
    def _wordnet_words(
        root: str, named: set, table: WordTable, exclude=frozenset(), max_depth: int = 99
    ) -> set[str]:
        """One- and two-word lower-case lemmas of ``root`` and its hyponyms down to
        ``max_depth`` levels, but those in ``named`` or ``exclude``."""
        from vla_gr.agent.reading.vocabulary import _closure, _wordnet

        wn = _wordnet()
        out = set()
        for synset, depth in _closure(wn.synset(root)).items():
            if depth > max_depth:
                continue
            for lemma in synset.lemma_names():
                phrase = tuple(request_words(normalise_request(lemma.replace("_", " "))))
                if phrase and phrase not in named and len(phrase) <= 2 and lemma.islower():
                    text = " ".join(phrase)
                    if text not in exclude and all(w.isalpha() for w in phrase):
                        out.add(text)
        return out

    @staticmethod
    def _adjectives() -> set[str]:
        """WordNet's one-word adjectives (head and satellite), lower case."""
        from vla_gr.agent.reading.vocabulary import _wordnet

        wn = _wordnet()
        return {
            lemma for pos in ("a", "s") for lemma in wn.all_lemma_names(pos)
            if lemma.isalpha() and lemma.islower() and 3 <= len(lemma) <= 10
        }  # fmt: skip

    # -- pieces -------------------------------------------------------------------------
    @staticmethod
    def _pick(rng: np.random.Generator, options):
        return options[int(rng.integers(len(options)))]

    def _weighted(self, rng, pairs: list[tuple[str, float]]) -> str:
        weights = np.array([w for _, w in pairs], dtype=np.float64)
        return pairs[int(rng.choice(len(pairs), p=weights / weights.sum()))][0]

    def _noun(self, rng, category: str | None) -> str:
        if category is None:
            return self._pick(rng, self.unknown_objects)
        return self._weighted(rng, self.nouns[category])

    def _room(self, rng, room: str | None) -> str:
        if room is None:
            common = rng.random() < 0.5
            return self._pick(rng, self.common_places if common else self.unknown_rooms)
        return self._weighted(rng, self.room_words[room])

    def _colour(self, rng, colour: str | None) -> str:
        if colour is None:
            common = rng.random() < 0.5
            return self._pick(rng, self.common_colours if common else self.unknown_colours)
        words = COLOUR_WORDS[colour]
        return words[0] if rng.random() < 0.85 else self._pick(rng, words)

    # -- one description of a goal ---------------------------------------------------------
    def _goal_phrase(self, rng, noun, colour, room, anchor, goal_tag="GOAL") -> list:
        """Segments [(text, tag)] describing the goal in one of many shapes."""
        det = self._pick(rng, DETERMINERS)
        seg: list[tuple[str, str]] = []
        size = []  # a word saying what it is like: "big", "potted", "spotted"
        if rng.random() < 0.14:
            size = [(self._pick(rng, SIZE if rng.random() < 0.5 else self.adjectives), "O")]
        colour_tag = "COLOUR" if goal_tag == "GOAL" else goal_tag
        room_tag = "ROOM" if goal_tag == "GOAL" else goal_tag
        anchor_tag = "ANCHOR" if goal_tag == "GOAL" else goal_tag
        near = [
            (self._pick(rng, NEAR), "O"),
            (self._pick(rng, ("the", "the", "a", "my", "")), "O"),
        ]
        anchor_seg = []
        if anchor is not None:
            anchor_colour = []
            if rng.random() < 0.05:
                anchor_colour = [(self._colour(rng, self._pick(rng, list(COLOUR_WORDS))), "O")]
            anchor_seg = near + anchor_colour + [(anchor, anchor_tag)]
        room_seg = []
        if room is not None:
            prep = PLACE_PREP if room in self._other_places else ROOM_PREP
            room_seg = [(self._pick(rng, prep), "O"), (room, room_tag)]
        shape = rng.random()
        if colour is not None and shape < 0.12:  # relative clause or appositive for colour
            form = self._pick(rng, ("that is", "that's", "which is", ", the", "- the", "(", ","))
            seg = [(det, "O")] + size + [(noun, goal_tag)]
            if form in (", the", "- the"):
                seg += [(form, "O"), (colour, colour_tag), ("one", "O")]
            elif form == "(":
                seg += [("(", "O"), (colour, colour_tag), (")", "O")]
            elif form == ",":
                seg += [(",", "O"), (colour, colour_tag)]
            else:
                seg += [(form, "O"), (colour, colour_tag)]
            rest = [room_seg, anchor_seg]
        elif room is not None and shape < 0.36 and room not in self._other_places:
            # a room of the house as a modifier, possessive or bare (a place no table holds
            # is said with a preposition: an unknown word before the noun is what it is like)
            form = rng.random()
            lead = [(self._pick(rng, ("the", "the", "my", "")), "O")]
            colour_seg = [(colour, colour_tag)] if colour else []
            if form < 0.3:  # "the kitchen's red chair"
                seg = lead + [(room + "'s", room_tag)] + colour_seg + size + [(noun, goal_tag)]
            elif form < 0.6:  # "the red kitchen chair"
                seg = lead + colour_seg + [(room, room_tag)] + size + [(noun, goal_tag)]
            elif form < 0.72:  # "the kitchen red chair"
                seg = lead + [(room, room_tag)] + colour_seg + size + [(noun, goal_tag)]
            else:  # "red chair kitchen", "red chair - kitchen"
                mark = self._pick(rng, ("", "", "", "-", ",", ":", "in", "in the", "/"))
                seg = lead + colour_seg + [(noun, goal_tag), (mark, "O"), (room, room_tag)]
            rest = [anchor_seg]
            room_seg = []
        elif anchor is not None and shape < 0.38:  # the anchor said first or after "it"
            form = self._pick(rng, ANCHOR_FIRST)
            colour_seg = [(colour, colour_tag)] if colour else []
            seg = []
            for piece in form.split(" "):
                if piece == "{a}":
                    seg.append((anchor, anchor_tag))
                elif piece == "{n}":
                    seg += colour_seg + [(noun, goal_tag)]
                else:
                    seg.append((piece, "O"))
            rest = [room_seg]
        elif shape < 0.46 and (room is not None or anchor is not None):  # relative clause
            seg = [(det, "O")] + ([(colour, colour_tag)] if colour else []) + size
            seg += [(noun, goal_tag), (self._pick(rng, ("that is", "that's", "which is")), "O")]
            rest = [room_seg, anchor_seg]
        else:
            seg = [(det, "O")] + ([(colour, colour_tag)] if colour else []) + size
            seg += [(noun, goal_tag)]
            rest = [room_seg, anchor_seg]
        if rng.random() < 0.5:
            rest = rest[::-1]
        for part in rest:
            if part:
                seg += ([("and", "O")] if rng.random() < 0.1 and seg[-1][1] != "O" else []) + part
        if colour is not None and shape >= 0.12 and rng.random() < 0.12:  # colour said last
            seg = [s for s in seg if s != (colour, colour_tag)]
            seg += [(self._pick(rng, (", the", "- the", ", that", ", the", "."))[0:], "O")]
            seg += [(colour, colour_tag), (self._pick(rng, ("one", "one", "")), "O")]
        return seg

    def goal_description(self, rng: np.random.Generator) -> str:
        """A house object described as a request would ("the green couch in the kitchen",
        "my kitchen's plant"), for sentences that name one and ask for nothing."""
        goal = self._pick(rng, self.goal_categories)
        colours = list(COLOUR_WORDS)
        colour = self._colour(rng, self._pick(rng, colours)) if rng.random() < 0.6 else None
        room = self._room(rng, self._pick(rng, self.rooms)) if rng.random() < 0.25 else None
        anchor = None
        if rng.random() < 0.15:
            anchor = self._noun(rng, self._pick(rng, [c for c in self.categories if c != goal]))
        segments = self._goal_phrase(rng, self._noun(rng, goal), colour, room, anchor)
        return " ".join(text for text, _ in segments if text)

    def negated_command(self, rng: np.random.Generator) -> str:
        """A request told the other way round, which asks to go nowhere: "don't go to the red
        chair", "please stay away from the couch in the kitchen", "no need to find the bed"."""
        goal = self.goal_description(rng)
        if rng.random() < 0.55:
            text = f"{self._pick(rng, DO_NOT)} {self._pick(rng, VERBS)} {goal}"
        else:
            text = f"{self._pick(rng, KEEP_AWAY)} {goal}"
        if rng.random() < 0.3:
            text = f"{self.opener(rng)} {text}"
        return text

    def opener(self, rng: np.random.Generator) -> str:
        """Words that open a message without asking anything: "hey robot,", "good morning."."""
        openers = [p for p in POLITE_BEFORE if "you" not in p and p not in ("please", "pls")]
        return self._pick(
            rng,
            openers
            + [
                "good morning.",
                "hello robot.",
                "fyi",
                "btw",
                "just so you know,",
                "heads up:",
                "oh and",
            ],
        )

    # -- one request ------------------------------------------------------------------------
    def sample(self, rng: np.random.Generator) -> LabelledRequest:
        fields = {"category": None, "color": None, "room": None, "anchor": None}
        if rng.random() < 0.06:
            return self._finish(rng, self._nothing(rng), fields, "nothing")
        fields["category"] = goal = self._pick(rng, self.goal_categories)
        unknown = rng.random()  # which part (if any) names nothing a table holds
        refuse = None
        if unknown < 0.07:
            fields["category"], refuse = None, "unknown_object"
        noun = self._noun(rng, fields["category"])
        colour = room = anchor = None
        if rng.random() < 0.7:
            fields["color"] = self._pick(rng, list(COLOUR_WORDS))
            if 0.07 <= unknown < 0.11:
                fields["color"], refuse = None, "unknown_colour"
            colour = self._colour(rng, fields["color"])
        if rng.random() < 0.45:
            fields["room"] = self._pick(rng, self.rooms)
            if 0.11 <= unknown < 0.15:
                fields["room"], refuse = None, "unknown_room"
            room = self._room(rng, fields["room"])
        if rng.random() < 0.35:
            fields["anchor"] = self._pick(rng, [c for c in self.categories if c != goal])
            if 0.15 <= unknown < 0.17:
                fields["anchor"], refuse = None, "unknown_anchor"
            anchor = self._noun(rng, fields["anchor"])
        if 0.17 <= unknown < 0.23:
            return self._finish(rng, self._negation(rng, noun, goal), fields, "negation")
        if 0.23 <= unknown < 0.29:
            segments = self._two_goals(rng, noun, colour, room, anchor)
            return self._finish(rng, segments, fields, "two_goals")
        phrase = self._goal_phrase(rng, noun, colour, room, anchor)
        return self._finish(rng, self._frame(rng, phrase, room), fields, refuse)

    def _frame(self, rng, phrase: list, room: str | None) -> list:
        style = rng.random()
        if style < 0.38:
            seg = [(self._pick(rng, VERBS), "O")] + phrase
        elif style < 0.55:  # the goal said first
            seg = phrase + [(self._pick(rng, (" -", ",", ".", "", ":", "...")), "O")]
            seg += [(self._pick(rng, FRONTED_COMMANDS), "O")] if rng.random() < 0.8 else []
        elif style < 0.67:
            seg = [(self._pick(rng, WISHES), "O")] + phrase
        elif style < 0.80:
            question = self._pick(rng, QUESTIONS)
            seg = [(question[0], "O")] + phrase + [(question[1], "O")]
        elif style < 0.88 and room is not None:  # the room said first
            lead = self._pick(rng, ("go into the", "in the", "head to the", "enter the", "",
                                    "the", "over in the", "in my"))  # fmt: skip
            tail = self._pick(rng, ("and find", ", find", "- find", "and go to", ", there's",
                                    ",", ":", "-", ".", ", the", "- the"))  # fmt: skip
            inner = [s for s in phrase if s != (room, "ROOM") and s[0] not in ROOM_PREP]
            seg = [(lead, "O"), (room, "ROOM"), (tail, "O")] + inner
        else:
            seg = [(self._pick(rng, VERBS), "O")] + phrase
        if rng.random() < 0.35:
            seg = [(self._pick(rng, POLITE_BEFORE), "O")] + seg
        if rng.random() < 0.25:
            seg = seg + [(self._pick(rng, POLITE_AFTER), "O")]
        if rng.random() < 0.2:
            context = [(self._pick(rng, CONTEXT), "O")]
            seg = context + seg if rng.random() < 0.7 else seg + [(".", "O")] + context
        if rng.random() < 0.12:  # a sentence about some other object: no goal in it
            other = OBJECT_CONTEXT[int(rng.integers(len(OBJECT_CONTEXT)))]
            other = other.format(o=self._pick(rng, self.unknown_objects))
            link = self._pick(rng, (".", "-", ",", ";", "so"))
            seg = (
                [(other, "O"), (link, "O")] + seg
                if rng.random() < 0.7
                else (seg + [(link, "O"), (other, "O")])
            )
        if rng.random() < 0.15:  # what the user will do there, with any word
            doing = self._pick(rng, DOING).format(w=self._pick(rng, self.fillers))
            link = self._pick(rng, (",", "-", ".", "so", "because", "and"))
            seg = (
                seg + [(link, "O"), (doing, "O")]
                if rng.random() < 0.6
                else ([(doing, "O"), (link, "O")] + seg)
            )
        return seg

    def _nothing(self, rng) -> list:
        """Words that ask for nothing: chat, mashed keys, unrelated words, empty."""
        style = rng.random()
        if style < 0.4:
            return [(self._pick(rng, CHAT), "O")]
        if style < 0.7:
            n = int(rng.integers(1, 4))
            words = [
                "".join(self._pick(rng, GIBBERISH_LETTERS) for _ in range(rng.integers(2, 9)))
                for _ in range(n)
            ]
            return [(" ".join(words), "O")]
        if style < 0.95:
            n = int(rng.integers(1, 6))
            return [(" ".join(self._pick(rng, self.fillers) for _ in range(n)), "O")]
        return [("", "O")]

    def _negation(self, rng, noun: str, goal: str) -> list:
        form, needs = self._pick(rng, NEGATIONS)
        colour = self._colour(rng, self._pick(rng, list(COLOUR_WORDS)))
        room = self._room(rng, self._pick(rng, self.rooms))
        anchor = self._noun(rng, self._pick(rng, [c for c in self.categories if c != goal]))
        seg: list[tuple[str, str]] = [(self._pick(rng, VERBS), "O")]
        tags = {"n": (noun, "GOAL"), "c": (colour, "COLOUR"), "r": (room, "ROOM"),
                "a": (anchor, "ANCHOR")}  # fmt: skip
        for piece in form.split(" "):
            if piece.startswith("{") and piece.endswith("}"):
                seg.append(tags[piece[1:-1]])
            elif piece.strip(",") in NEGATION_WORDS:
                seg.append((piece, "NEG"))
            else:
                seg.append((piece, "O"))
        return seg

    def _two_goals(self, rng, noun, colour, room, anchor) -> list:
        """Two goals: joined ("... and then ..."), asked for together ("both ... and ..."),
        one a stop on the way to the other, or the first said in a clause ("after ...")."""
        first = self._goal_phrase(rng, noun, colour, room, None)
        second_goal = self._pick(rng, self.categories)  # a landmark too: "the chair & the table"
        second_colour = self._colour(rng, self._pick(rng, list(COLOUR_WORDS)))
        second = self._goal_phrase(
            rng,
            self._noun(rng, second_goal),
            second_colour if rng.random() < 0.4 else None,
            None,
            None,
            goal_tag="SECOND",
        )
        form = rng.random()
        if form < 0.15:
            seg = [(self._pick(rng, BOTH), "O")] + first
            seg += [(self._pick(rng, BOTH_AND), "O")] + second
            seg += [(self._pick(rng, EACH), "O")] if rng.random() < 0.5 else []
        elif form < 0.3:
            stop, way = self._pick(rng, ON_THE_WAY)
            seg = [(stop, "O")] + first + [(way, "O")] + second
        elif form < 0.42:
            before, then = self._pick(rng, AFTER)
            seg = [(before, "O")] + first + [(then, "O")] + second
        else:
            lead = self._pick(rng, ("first", "go to", "first go to", "find", ""))
            lead = self._pick(rng, VERBS) if rng.random() < 0.4 else lead
            link = [(self._pick(rng, AND if rng.random() < 0.4 else SECOND), "O")]
            verb = self._pick(rng, ("", "go to", "find", "the"))
            verb = [(verb, "O")] if rng.random() < 0.5 else []
            seg = [(lead, "O")] + first + link + verb + second
        if rng.random() < 0.3:
            seg = [(self._pick(rng, POLITE_BEFORE), "O")] + seg
        if rng.random() < 0.2:
            seg = seg + [(self._pick(rng, POLITE_AFTER), "O")]
        return seg

    # -- surface: words, typing slips --------------------------------------------------------
    def _finish(self, rng, segments: list, fields: dict, refuse: str | None) -> LabelledRequest:
        words: list[str] = []
        tags: list[str] = []
        for text, tag in segments:
            for word in request_words(normalise_request(text)):
                words.append(word)
                tags.append(tag)
        if words and rng.random() < 0.2:  # one typing slip in one word of 4 letters or more
            long = [k for k, w in enumerate(words) if len(w) >= 4 and w.isalpha()]
            named = [k for k in long if words[k] in self._field_words]
            if named and rng.random() < 0.5:  # in a field word: "bleu", "whit", "rom"
                long = named
            if long:
                k = long[int(rng.integers(len(long)))]
                words[k] = _slip(words[k], rng)
        assert all(t in TAGS for t in tags)
        return LabelledRequest(" ".join(words), tuple(words), tuple(tags), fields, refuse)

    def batch(self, n: int, seed: int) -> list[LabelledRequest]:
        rng = np.random.default_rng(seed)
        return [self.sample(rng) for _ in range(n)]


def _slip(word: str, rng: np.random.Generator) -> str:
    """``word`` with one typing slip: neighbours swapped, a letter dropped or doubled."""
    k = int(rng.integers(len(word) - 1))
    kind = rng.random()
    if kind < 0.45:
        return word[:k] + word[k + 1] + word[k] + word[k + 2 :]
    if kind < 0.75:
        return word[:k] + word[k + 1 :]
    return word[: k + 1] + word[k] + word[k + 1 :]
