"""The word tables: WordNet words for each class, by role, and typing slips repaired."""

import pytest

from vla_gr.agent.reading.vocabulary import Name, _slips, word_table

pytest.importorskip("wn")


@pytest.fixture(scope="module")
def table():
    return word_table()


@pytest.mark.parametrize(
    ("words", "kind", "name"),
    [
        (["couch"], "category", "sofa"),  # its first sense is sofa.n.01
        (["settee"], "category", "sofa"),  # a hyponym of sofa.n.01
        (["armchair"], "category", "chair"),
        (["television"], "category", "tv_monitor"),
        (["potted", "plant"], "category", "plant"),  # the head names it
        (["desk"], "category", "table"),
        (["cupboard"], "category", "cabinet"),
        (["toilet"], "category", "toilet"),
        (["toilet"], "room", "bathroom"),  # the same word, as a room
        (["lounge"], "category", "sofa"),
        (["lounge"], "room", "living_room"),
        (["living", "room"], "room", "living_room"),
        (["kitchen's"], "room", "kitchen"),  # a possessive
        (["chairs"], "category", "chair"),  # a plural
        (["crimson"], "colour", "red"),
        (["reddish"], "colour", "red"),
    ],
)
def test_words_name_their_class(table, words, kind, name):
    assert table.name_in(words, kind) == Name(kind if kind != "colour" else "colour", name)


@pytest.mark.parametrize(
    ("words", "kind"),
    [
        (["piano"], "category"),
        (["garage"], "room"),
        (["pink"], "colour"),
        (["navy"], "colour"),  # a shade with a name of its own: no object is navy
        (["qwzx"], "category"),
    ],
)
def test_words_no_table_holds_name_nothing(table, words, kind):
    assert table.name_in(words, kind) is None


@pytest.mark.parametrize(
    ("typed", "meant"),
    [("chiar", "chair"), ("tabel", "table"), ("kichen", "kitchen"), ("yellwo", "yellow"),
     ("plnat", "plant"), ("bedrooom", "bedroom"), ("couhc", "couch")],
)  # fmt: skip
def test_one_typing_slip_from_one_table_word_is_repaired(table, typed, meant):
    assert meant in _slips(typed)[0] | _slips(typed)[1] | _slips(typed)[2]
    assert table.repair(typed) == meant


@pytest.mark.parametrize("word", ["bad", "chai", "the", "qwzxplorf", "sofa"])
def test_known_words_short_words_and_far_words_are_left_alone(table, word):
    assert table.repair(word) == word


@pytest.mark.parametrize(("typed", "meant"), [("bde", "bed"), ("hal", "hall"), ("rde", "red")])
def test_a_three_letter_word_is_repaired_through_a_swap_or_a_lost_letter(table, typed, meant):
    assert table.repair(typed) == meant


@pytest.mark.parametrize("word", ["lol", "omg", "idk", "bwd", "lox"])
def test_three_letter_mistypes_and_chat_words_are_left_alone(table, word):
    # "lol" is a mistype of "loo", "bwd" of "bed", "lox" an added letter to "lo"... : at
    # three letters such slips turn most strings into some word, so none is repaired
    assert table.repair(word) == word


@pytest.mark.parametrize("word", ["khaki", "russet", "golden", "beige", "teal", "cream", "slate"])
def test_colours_wordnet_knows_beyond_the_eight_are_other_colours(table, word):
    assert word in table.other_colours and table.look_up([word], "colour") is None


def test_the_colours_the_world_says_no_object_has_are_other_colours_to_the_reader(table):
    # one account of colour: a word the world grounds to no object ("the navy bed" fits
    # nothing) is never read as one of the eight, so the agent refuses it instead of acting
    from vla_gr.agent.reading.vocabulary import COLOUR_WORDS
    from vla_gr.envs.grounding import OTHER_COLOURS

    shades = {w for words in COLOUR_WORDS.values() for w in words}
    assert not shades & set(OTHER_COLOURS)
    assert set(OTHER_COLOURS) <= table.other_colours


def test_features_mark_category_room_colour_relation_and_negation_words(table):
    from vla_gr.agent.reading.vocabulary import FEATURES

    words = [
        "the",
        "red",
        "chiar",
        "that",
        "isn't",
        "next",
        "to",
        "the",
        "tv",
        "in",
        "the",
        "kitchen",
    ]
    fixed, vectors = table.features(words)
    assert fixed[2] == "chair"
    on = [{FEATURES[k] for k, v in enumerate(vec) if v} for vec in vectors]
    assert "colour" in on[1] and "goal_category" in on[2] and "typo_fixed" in on[2]
    assert "negation" in on[4] and "relation" in on[5] and "goal_category" in on[8]
    assert "room" in on[11] and "room" not in on[2]


@pytest.mark.parametrize(
    ("typed", "meant"),
    [("rm", "room"), ("bdrm", "bedroom"), ("nxt", "next"), ("2", "to"), ("ot", "to"),
     ("ni", "in"), ("yb", "by")],
)  # fmt: skip
def test_short_forms_and_swapped_two_letter_function_words_are_read_as_the_word(
    table, typed, meant
):
    assert table.repair(typed) == meant


@pytest.mark.parametrize("word", ["on", "no", "to", "tv", "ox"])
def test_two_letter_words_that_are_no_swapped_function_word_are_left_alone(table, word):
    assert table.repair(word) == word


@pytest.mark.parametrize(
    ("word", "kind", "meant"),
    [("bleu", "colour", "blue"), ("whit", "colour", "white"), ("lining", "room", "living"),
     ("bleu", "room", None), ("blue", "colour", None), ("red", "category", "bed")],
)  # fmt: skip
def test_a_real_word_one_slip_from_a_table_word_of_a_kind_is_found_for_that_kind_only(
    table, word, kind, meant
):
    assert table.slip_name(word, kind) == meant


def test_slip_features_mark_a_known_word_one_slip_from_a_colour_or_room(table):
    from vla_gr.agent.reading.vocabulary import FEATURES

    fixed, vectors = table.features(["the", "bleu", "chair", "lining", "room"])
    on = [{FEATURES[k] for k, v in enumerate(vec) if v} for vec in vectors]
    assert fixed[1] == "bleu"  # a known word: not repaired, only marked
    assert "slip_colour" in on[1] and "colour" not in on[1]
    assert "slip_room" in on[3] and not any(f.startswith("slip_") for f in on[0] | on[2])


@pytest.mark.parametrize(
    ("words", "name"),
    [(["coat", "rack"], None), (["toilet", "paper"], None), (["bed", "sheets"], None),
     (["coffee", "table"], "table"), (["kitchen", "chair"], "chair")],
)  # fmt: skip
def test_a_class_word_inside_a_longer_noun_no_table_holds_names_nothing(table, words, name):
    found = table.name_in(words, "category")
    assert (found.name if found else None) == name


def test_the_longer_noun_around_an_object_word_is_found_in_the_request(table):
    words = ["find", "the", "trash", "can", "in", "the", "office"]
    assert table.compound_around(words, 3, 1) == slice(2, 4)  # "trash can" around "can"
    assert table.compound_around(["find", "the", "sofa", "bed"], 3, 1) is None  # a sofa
    assert table.compound_around(["the", "red", "chair"], 2, 1) is None
