"""The instruction reader: its config, attention pooling that ignores padding, confident
fields only (cached per string), and template words first when readings are combined."""

from __future__ import annotations

import pytest
import torch

from vla_gr.agent.perception import (
    InstructionReader,
    InstructionReaderConfig,
    Reading,
    instructed_anchor,
    instructed_category,
    instructed_room,
    read_instruction,
)
from vla_gr.agent.perception.instruction_reader import FIELDS

CONFIG = InstructionReaderConfig()
CATEGORIES, ROOMS = CONFIG.categories, CONFIG.room_types
TEMPLATE_TEXT = "Find the red chair near the bed in the kitchen"
HELD_OUT_TEXT = "search the house for the couch close to the houseplant"


def small(**kw) -> InstructionReader:
    torch.manual_seed(0)
    return InstructionReader(InstructionReaderConfig(token_dim=8, hidden=6, **kw)).eval()


@pytest.mark.parametrize(
    "key, value",
    [
        ("min_confidence", 0.0),
        ("min_confidence", -0.1),
        ("min_confidence", 1.01),
        ("hidden", 0),
        ("token_dim", 0),
        ("max_length", 0),
    ],
)
def test_config_refuses_out_of_range_settings_by_their_key(key, value):
    with pytest.raises(ValueError, match=rf"model\.instruction_reader\.{key}="):
        InstructionReaderConfig(**{key: value})


def test_config_classes_are_none_plus_categories_or_room_types():
    assert InstructionReaderConfig(min_confidence=1.0).min_confidence == 1.0  # (0, 1] closed at 1
    assert CONFIG.classes("room") == 1 + len(ROOMS) == 7
    assert CONFIG.classes("category") == CONFIG.classes("anchor") == 1 + len(CATEGORIES) == 9
    few = InstructionReaderConfig(categories=["chair", "bed"], room_types=["kitchen"])
    assert (few.classes("category"), few.classes("anchor"), few.classes("room")) == (3, 3, 2)
    assert FIELDS == ("category", "anchor", "room")


def test_forward_gives_one_row_of_logits_per_instruction_and_field():
    reader = small()
    logits = reader(torch.randn(3, 5, 8), torch.ones(3, 5, dtype=torch.long))
    assert {k: tuple(v.shape) for k, v in logits.items()} == {
        "category": (3, 9),
        "anchor": (3, 9),
        "room": (3, 7),
    }


def test_forward_ignores_padding_and_the_rest_of_the_batch():
    reader = small()
    torch.manual_seed(1)
    tokens = torch.randn(2, 4, 8)
    mask = torch.tensor([[1, 1, 1, 1], [1, 1, 0, 0]])
    out = reader(tokens, mask)
    # the same sequences with garbage tokens appended (masked out) and inside the padding
    garbage = tokens.clone()
    garbage[1, 2:] = 1e3
    padded = torch.cat([garbage, 50.0 * torch.randn(2, 3, 8)], dim=1)  # (2, 7, 8)
    padded_mask = torch.cat([mask, torch.zeros(2, 3, dtype=torch.long)], dim=1)
    again = reader(padded, padded_mask)
    alone = reader(tokens[1:, :2], mask[1:, :2])  # the short one without padding or batch
    for name in FIELDS:
        torch.testing.assert_close(again[name], out[name])
        torch.testing.assert_close(alone[name], out[name][1:])


def test_forward_pools_the_tokens_whatever_their_order():
    reader = small()
    torch.manual_seed(2)
    tokens, mask = torch.randn(1, 6, 8), torch.ones(1, 6, dtype=torch.long)
    order = torch.tensor([3, 0, 5, 1, 4, 2])
    out, shuffled = reader(tokens, mask), reader(tokens[:, order], mask[:, order])
    for name in FIELDS:
        torch.testing.assert_close(shuffled[name], out[name])


def test_one_real_token_is_read_by_each_head_as_it_is():
    reader = small()
    torch.manual_seed(3)
    tokens = torch.randn(1, 3, 8)
    mask = torch.tensor([[0, 1, 0]])  # the pooled state is token 1 itself
    out = reader(tokens, mask)
    for name in FIELDS:
        torch.testing.assert_close(out[name], reader.heads[name](tokens[:, 1]))


def test_forward_refuses_tokens_of_another_width():
    reader = small()
    with pytest.raises(ValueError, match=r"tokens must be \(B, L, 8\)"):
        reader(torch.randn(2, 4, 16), torch.ones(2, 4))
    with pytest.raises(ValueError, match="tokens must be"):
        reader(torch.randn(4, 8), torch.ones(1, 4))


def one_hot(field_classes: dict[str, tuple[int, float]]) -> dict[str, torch.Tensor]:
    """{field: (1, C)} with probability ``p`` on class ``k`` and the rest spread evenly."""
    out = {}
    for name in FIELDS:
        k, p = field_classes[name]
        C = CONFIG.classes(name)
        row = torch.full((1, C), (1.0 - p) / (C - 1))
        row[0, k] = p
        out[name] = row
    return out


def fake_probabilities(reader, monkeypatch, answers: dict[str, dict]) -> list[list[str]]:
    """Make ``reader.probabilities`` answer ``answers[instruction]``; returns its calls."""
    calls: list[list[str]] = []

    def probabilities(instructions):
        calls.append(list(instructions))
        return one_hot(answers[instructions[0]])

    monkeypatch.setattr(reader, "probabilities", probabilities)
    return calls


def test_read_fills_only_confident_named_fields_in_the_checks_indexing(monkeypatch):
    reader = small(min_confidence=0.75)
    answers = {
        # category: class 3 = bed (1-based, like instructed_category); anchor: "none" wins;
        # room: class 2 (living_room) but not confident enough
        "a": {"category": (3, 0.95), "anchor": (0, 0.99), "room": (2, 0.6)},
        # exactly at min_confidence counts; room class 2 -> index 1 (0-based, instructed_room)
        "b": {"category": (8, 0.75), "anchor": (6, 1.0), "room": (2, 0.75)},
        # first class and last room; category below the threshold by a hair
        "c": {"category": (1, 0.74), "anchor": (1, 0.8), "room": (6, 0.9)},
    }
    fake_probabilities(reader, monkeypatch, answers)
    assert reader.read("a") == Reading(category=3, anchor=None, room=None)
    assert reader.read("b") == Reading(category=8, anchor=6, room=1)
    assert reader.read("c") == Reading(category=None, anchor=1, room=5)
    assert CATEGORIES[reader.read("b").category - 1] == "cabinet"
    assert ROOMS[reader.read("b").room] == "living_room"
    assert reader.read("a").source == {}  # the reader alone says who filled nothing


def test_read_fills_only_the_fields_it_is_given(monkeypatch):
    reader = small(fields=["category"])
    sure = {"category": (4, 1.0), "anchor": (2, 1.0), "room": (3, 1.0)}
    fake_probabilities(reader, monkeypatch, {"x": sure})
    assert reader.read("x") == Reading(category=4, anchor=None, room=None)
    for fields in (["colour"], ["room", "room"]):
        with pytest.raises(ValueError, match=r"model\.instruction_reader\.fields="):
            InstructionReaderConfig(fields=fields)


def test_readings_are_cached_per_instruction_until_train_or_eval(monkeypatch):
    reader = small()
    sure = {"category": (2, 1.0), "anchor": (0, 1.0), "room": (1, 1.0)}
    calls = fake_probabilities(reader, monkeypatch, {"x": sure, "y": sure})
    first = reader.read("x")
    assert reader.read("x") is first and calls == [["x"]]
    reader.read("y")
    assert calls == [["x"], ["y"]]
    reader.eval()  # the weights may have changed: read again
    assert reader.read("x") == first and calls == [["x"], ["y"], ["x"]]
    reader.train()
    reader.read("x")
    reader.read("y")
    assert calls == [["x"], ["y"], ["x"], ["x"], ["y"]]


def test_template_parse_alone_without_a_reader():
    expected = (
        instructed_category(TEMPLATE_TEXT, CATEGORIES),
        instructed_anchor(TEMPLATE_TEXT, CATEGORIES),
        instructed_room(TEMPLATE_TEXT, ROOMS),
    )
    assert expected == (1, 3, 0)  # chair, bed, kitchen
    reading = read_instruction(TEMPLATE_TEXT, CATEGORIES, ROOMS)
    assert (reading.category, reading.anchor, reading.room) == expected
    assert reading.source == dict.fromkeys(FIELDS, "template")
    assert read_instruction(HELD_OUT_TEXT, CATEGORIES, ROOMS) == Reading()


class FakeReader:
    """Answers every instruction with one reading and records what it was asked."""

    def __init__(self, reading: Reading):
        self.reading, self.asked = reading, []

    def read(self, instruction: str) -> Reading:
        self.asked.append(instruction)
        return self.reading


def test_template_words_win_and_the_reader_fills_only_the_empty_fields():
    reader = FakeReader(Reading(category=5, anchor=6, room=3))
    reading = read_instruction(TEMPLATE_TEXT, CATEGORIES, ROOMS, reader)
    assert reading == Reading(1, 3, 0, source=dict.fromkeys(FIELDS, "template"))
    # a template goal and room word the templates do not have: the reader fills the rest
    reading = read_instruction("find the chair in the lounge", CATEGORIES, ROOMS, reader)
    assert reading == Reading(
        1, 6, 3, source={"category": "template", "anchor": "reader", "room": "reader"}
    )
    reading = read_instruction(HELD_OUT_TEXT, CATEGORIES, ROOMS, reader)
    assert reading == Reading(5, 6, 3, source=dict.fromkeys(FIELDS, "reader"))
    assert reader.asked[-1] == HELD_OUT_TEXT


def test_a_field_neither_names_stays_empty_and_has_no_source():
    reader = FakeReader(Reading(category=2, anchor=None, room=None))
    reading = read_instruction("go into the lounge and find the couch", CATEGORIES, ROOMS, reader)
    assert reading == Reading(category=2, source={"category": "reader"})
    assert reading.anchor is None and reading.room is None


def test_a_real_reader_with_chosen_probabilities_combines_with_the_template(monkeypatch):
    reader = small()
    answers = {
        HELD_OUT_TEXT: {"category": (2, 0.99), "anchor": (6, 0.95), "room": (0, 0.97)},
        "find the chair in the lounge": {
            "category": (4, 0.99),  # the template's chair wins
            "anchor": (0, 0.99),
            "room": (2, 0.93),
        },
    }
    fake_probabilities(reader, monkeypatch, answers)
    reading = read_instruction(HELD_OUT_TEXT, CATEGORIES, ROOMS, reader)
    assert reading == Reading(2, 6, None, source={"category": "reader", "anchor": "reader"})
    reading = read_instruction("find the chair in the lounge", CATEGORIES, ROOMS, reader)
    assert reading == Reading(1, None, 1, source={"category": "template", "room": "reader"})
    assert ROOMS[reading.room] == "living_room"


def test_encode_and_probabilities_on_a_small_sentence_model(tiny_bert):
    torch.manual_seed(0)
    config = InstructionReaderConfig(token_dim=16, hidden=8)
    reader = InstructionReader(config, model_path=tiny_bert).eval()
    texts = ["find the red chair near the bed in the kitchen", "find the sofa"]
    tokens, mask = reader.encode(texts)
    assert tokens.shape == (2, 12, 16) and tokens.dtype == torch.float32  # [CLS] 10 words [SEP]
    assert mask.tolist() == [[1] * 12, [1] * 5 + [0] * 7]
    probs = reader.probabilities(texts)
    assert {k: tuple(v.shape) for k, v in probs.items()} == {
        "category": (2, 9),
        "anchor": (2, 9),
        "room": (2, 7),
    }
    for name in FIELDS:
        torch.testing.assert_close(probs[name].sum(-1), torch.ones(2))
        assert (probs[name] > 0).all()
    # what the reader says of a text does not depend on what it is batched with
    alone = reader.probabilities(texts[1:])
    for name in FIELDS:
        torch.testing.assert_close(alone[name], probs[name][1:], atol=1e-5, rtol=0)
    # the weights saved are the reader's own; the sentence model is neither saved nor trained
    assert all(k.startswith(("scores.", "heads.")) for k in reader.state_dict())


def test_an_encoder_of_another_width_is_refused(tiny_bert):
    reader = InstructionReader(InstructionReaderConfig(token_dim=8), model_path=tiny_bert)
    with pytest.raises(ValueError, match=r"tokens must be \(B, L, 8\); got \(1, \d+, 16\)"):
        reader.probabilities(["find the chair"])
