"""From word roles to a reading: spans, names, refusals and confidences, with the tagger's
probabilities given (one-hot or hand-made), so the rules are tested without training."""

import pytest
import torch

from vla_gr.agent.reading import TAGS, InstructionReader, ReaderConfig
from vla_gr.agent.reading.text import normalise_request, request_words

pytest.importorskip("wn")


def read(text: str, tags: str, sure: float = 1.0):
    """The reading of ``text`` when the tagger says ``tags`` (one letter per word: O, G
    goal, C colour, R room, A anchor, N negation, S second goal) with probability ``sure``."""
    reader = InstructionReader(ReaderConfig(min_confidence=0.5))
    words = request_words(normalise_request(text))
    letters = {"O": "O", "G": "GOAL", "C": "COLOUR", "R": "ROOM", "A": "ANCHOR", "N": "NEG",
               "S": "SECOND"}  # fmt: skip
    assert len(tags) == len(words), words
    probs = torch.full((len(words), len(TAGS)), (1 - sure) / (len(TAGS) - 1))
    for k, letter in enumerate(tags):
        probs[k, TAGS.index(letters[letter])] = sure
    fixed = [reader_table_fix(w) for w in words]
    return reader._reading(normalise_request(text), fixed, probs)


def reader_table_fix(word: str) -> str:
    from vla_gr.agent.reading.vocabulary import word_table

    return word_table().repair(word)


def test_a_full_description_is_read_into_its_fields():
    r = read("Hey robot, the crimson settee next to the telly in the lounge pls", "OOOOCGOOOAOORO")
    assert r.fields() == {"category": "sofa", "color": "red", "room": "living_room",
                          "anchor": "tv_monitor"}  # fmt: skip
    assert r.understood and r.reason is None and r.relation == "near"
    assert r.phrase == "find the red sofa in the living room next to the tv"
    assert all(v == pytest.approx(1.0) for v in r.confidence.values())


def test_a_typing_slip_in_the_noun_is_repaired():
    r = read("find teh red chiar", "OOCG")
    assert r.category == "chair" and r.color == "red" and r.understood


@pytest.mark.parametrize(
    ("text", "tags", "said"),
    [
        ("find the piano", "OOG", "'piano' is nothing I know"),
        ("take me to the grand piano in the garage", "OOOOGGOOR", "'grand piano'"),
        ("qwzx plorf", "OO", "no object to find is named"),
        ("", "", "the request is empty"),
        ("go to the desk", "OOOG", "'table' is no goal I can find"),
        ("the pink sofa", "OCG", "'pink' is no colour, room or object I know"),
        ("the chair in the garage", "OGOOR", "'garage'"),
        ("the chair that isn't red", "OGONC", "say which one it is"),
        ("go to the red chair and then the sofa", "OOOCGOOOS", "one goal at a time: 'sofa'"),
        ("the red chair, the blue one", "OCGOOCO", "two different color"),
    ],
)
def test_what_it_cannot_ground_it_does_not_act_on_and_says_why(text, tags, said):
    r = read(text, tags)
    assert not r.understood and r.phrase == ""
    assert said in r.reason and "\n" not in r.reason
    if "nothing I know" in said or "no object" in said or "empty" in said:
        assert "I can find: chair, sofa, bed, toilet, tv, plant" in r.reason


def test_a_field_read_with_low_confidence_is_not_acted_on():
    assert read("find the red chair", "OOCG", sure=0.9).understood
    r = read("find the red chair", "OOCG", sure=0.4)
    assert not r.understood and r.reason.startswith("unsure of the")


def test_confidence_of_an_absent_field_is_the_chance_no_word_has_its_role():
    r = read("find the chair", "OOG", sure=0.8)
    other = 0.2 / (len(TAGS) - 1)  # each other role's probability per word
    assert r.confidence["room"] == pytest.approx((1 - other) ** 3)
    assert r.confidence["category"] == pytest.approx(0.8)


def test_the_checks_indices_follow_the_configured_classes():
    reader = InstructionReader(ReaderConfig())
    r = read("the purple bed by the cabinet in the bedroom", "OCGOOAOOR")
    assert reader.indices(r) == (3, 8, 2)  # bed, cabinet (1-based), bedroom (0-based)
    assert r.as_dict()["understood"] is True and r.as_dict()["anchor"] == "cabinet"


def test_the_whole_dwelling_is_no_room_and_no_unknown_word():
    r = read("find the red chair in my house", "OOCGOOR")
    assert r.understood and r.room is None and r.unknown == ()
    assert not read("find the red chair in the garage", "OOCGOOR").understood


def test_a_span_tagged_as_a_field_is_read_through_a_slip_onto_a_real_word():
    r = read("go to the bleu chair in the lining room", "OOOCGOORR")
    assert (r.color, r.category, r.room) == ("blue", "chair", "living_room") and r.understood


def test_a_colour_word_left_without_a_role_makes_the_request_not_understood():
    r = read("the chair red", "OGO")
    assert not r.understood and r.reason == "'red': I could not tell what it describes"
    assert "red" in r.unknown


def test_a_colour_describing_the_anchor_is_no_unplaced_word():
    r = read("the chair next to the red table", "OGOOOOA")
    assert r.understood and r.anchor == "table" and r.color is None


def test_a_noun_no_table_holds_is_not_read_through_its_head_or_a_slip():
    r = read("find the coat rack in the hallway", "OOGGOOR")  # "rack" (slang bed), "cot"
    assert not r.understood and r.category is None and "coat rack" in r.reason


def test_a_colour_no_table_holds_said_before_the_goal_is_not_dropped():
    r = read("go to the beige chair", "OOOOG")
    assert not r.understood and "beige" in r.reason


def test_a_colour_no_table_holds_read_as_part_of_the_noun_is_not_dropped():
    r = read("go to the teal chair", "OOOGG")
    assert not r.understood and "teal" in r.reason


def test_a_hyphen_inside_a_word_joins_the_words_of_a_room():
    r = read("the living-room chair that's black", "ORRGOC")
    assert (r.room, r.category, r.color) == ("living_room", "chair", "black") and r.understood
