"""The request grammar: reproducible, every word labelled, and its labels say what it means:
decoding a request's own labels gives the fields it was made from, and a request it marks as
one to refuse decodes to a reading that is not understood."""

import pytest
import torch

from vla_gr.agent.reading import TAGS, InstructionReader, ReaderConfig
from vla_gr.agent.reading.vocabulary import word_table
from vla_gr.envs.scene import CATEGORIES, GOAL_CATEGORIES, ROOM_TYPES
from vla_gr.training.request_grammar import RequestGrammar

pytest.importorskip("wn")


@pytest.fixture(scope="module")
def grammar():
    return RequestGrammar(word_table(), GOAL_CATEGORIES, CATEGORIES, ROOM_TYPES)


@pytest.fixture(scope="module")
def requests(grammar):
    return grammar.batch(600, seed=3)


def test_the_same_seed_gives_the_same_requests(grammar, requests):
    again = grammar.batch(600, seed=3)
    assert [r.text for r in again] == [r.text for r in requests]
    assert [r.text for r in grammar.batch(50, seed=4)] != [r.text for r in requests[:50]]


def test_every_word_has_one_known_tag(requests):
    for r in requests:
        assert len(r.words) == len(r.tags) and set(r.tags) <= set(TAGS)
        assert r.text == " ".join(r.words)


def test_the_mix_holds_every_kind_of_request(requests):
    kinds = {r.refuse for r in requests}
    assert kinds >= {None, "nothing", "unknown_object", "unknown_colour", "unknown_room",
                     "negation", "two_goals"}  # fmt: skip
    acted = [r for r in requests if r.refuse is None]
    assert 0.6 < len(acted) / len(requests) < 0.85
    assert any(r.fields["anchor"] for r in acted) and any(r.fields["room"] for r in acted)


def test_decoding_its_own_labels_gives_the_fields_it_was_made_from(requests):
    """Labels and word tables agree: the reader's rules on the grammar's own tags read the
    fields back (a typing slip that makes another real word is the one allowed miss)."""
    reader = InstructionReader(ReaderConfig(min_confidence=0.5))
    table = word_table()
    right = refused = acted = refusals = 0
    for r in requests:
        probs = torch.zeros(len(r.words), len(TAGS))
        for k, tag in enumerate(r.tags):
            probs[k, TAGS.index(tag)] = 1.0
        reading = reader._reading(r.text, [table.repair(w) for w in r.words], probs)
        if r.refuse is None:
            acted += 1
            right += reading.understood and reading.fields() == r.fields
        else:
            refusals += 1
            refused += not reading.understood
    assert right / acted >= 0.97, right / acted
    assert refused / refusals >= 0.97, refused / refusals


def test_a_second_goal_is_any_object_landmarks_included(grammar):
    """ "the chair and the table" is two goals even though a table is no goal to find."""
    table = word_table()
    seconds = set()
    for r in grammar.batch(3000, seed=5):
        if r.refuse == "two_goals":
            words = [w for w, t in zip(r.words, r.tags) if t == "SECOND"]
            named = table.name_in([table.repair(w) for w in words], "category")
            seconds.add(named.name if named else None)
    assert {"table", "cabinet"} <= seconds and set(GOAL_CATEGORIES) <= seconds


def test_two_goals_come_in_every_shape_and_each_names_a_second_goal(grammar):
    """Joined, asked for together ("both ... and ..."), a stop on the way to the other, or the
    first in a clause ("after the bed, go to ..."): a SECOND span, after the goal, every time."""
    shapes = {"both": 0, "way to": 0, "after": 0}
    for r in grammar.batch(3000, seed=6):
        if r.refuse != "two_goals":
            continue
        tags = list(r.tags)
        assert "SECOND" in tags and "GOAL" in tags
        assert tags.index("GOAL") < tags.index("SECOND")
        text = " ".join(r.words)
        for shape in shapes:
            shapes[shape] += f"{shape} " in f"{text} "
    assert min(shapes.values()) >= 5, shapes
