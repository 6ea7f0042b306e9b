"""The request intent head: pooling, and how the reader acts on its probability."""

import pytest
import torch

from vla_gr.agent.reading import TAGS, InstructionReader, ReaderConfig
from vla_gr.agent.reading.intent import RequestIntent, pooled_states
from vla_gr.agent.reading.text import normalise_request, request_words

pytest.importorskip("wn")


def test_pooled_states_average_the_words_under_the_mask_only():
    states = torch.tensor([[[1.0, 2.0], [3.0, 4.0], [100.0, 100.0]],
                           [[5.0, 6.0], [0.0, 0.0], [0.0, 0.0]]])  # (2, 3, 2)  # fmt: skip
    mask = torch.tensor([[1, 1, 0], [1, 0, 0]])  # (2, 3)
    assert torch.equal(pooled_states(states, mask), torch.tensor([[2.0, 3.0], [5.0, 6.0]]))
    empty = pooled_states(torch.zeros(1, 0, 2), torch.zeros(1, 0, dtype=torch.long))
    assert torch.equal(empty, torch.zeros(1, 2))  # an empty request: zeros, not NaN


def test_the_head_reads_the_pooled_state_only():
    torch.manual_seed(0)
    head = RequestIntent(token_dim=4, hidden=3).eval()
    states = torch.randn(1, 3, 4)  # (1, 3, 4)
    padded = torch.cat([states, 50 * torch.ones(1, 2, 4)], dim=1)  # (1, 5, 4)
    short = head(states, torch.ones(1, 3, dtype=torch.long))
    long = head(padded, torch.tensor([[1, 1, 1, 0, 0]]))
    assert short.shape == (1,) and torch.allclose(short, long)


def _read(text: str, tags: str, intent: float | None, min_intent: float = 0.5):
    config = ReaderConfig(min_confidence=0.5, intent=intent is not None, min_intent=min_intent)
    reader = InstructionReader(config)
    words = request_words(normalise_request(text))
    letters = {"O": "O", "G": "GOAL", "C": "COLOUR"}
    probs = torch.zeros(len(words), len(TAGS))  # (N, T)
    for k, letter in enumerate(tags):
        probs[k, TAGS.index(letters[letter])] = 1.0
    return reader.decode(normalise_request(text), words, probs, intent)


def test_a_sentence_below_min_intent_is_not_acted_on_and_says_why():
    remark = _read("that green chair is so ugly", "OCGOOO", intent=0.1)
    assert not remark.understood
    assert "does not ask me to go anywhere" in remark.reason
    assert "find the chair" in remark.reason
    assert remark.confidence["request"] == pytest.approx(0.1)
    assert (remark.category, remark.color) == ("chair", "green")  # the fields still read
    request = _read("go to the green chair", "OOOCG", intent=0.9)
    assert request.understood and request.confidence["request"] == pytest.approx(0.9)
    at = _read("go to the green chair", "OOOCG", intent=0.5, min_intent=0.5)
    assert at.understood  # at the threshold: acted on


def test_without_the_head_nothing_changes():
    reading = _read("that green chair is so ugly", "OCGOOO", intent=None)
    assert reading.understood and "request" not in reading.confidence
    reader = InstructionReader(ReaderConfig())
    assert reader.intent is None
    assert not any(k.startswith("intent.") for k in reader.state_dict())  # old checkpoints load


def test_a_more_specific_reason_comes_first():
    reading = _read("the purple piano is ugly", "OOGOO", intent=0.01)
    assert not reading.understood and "piano" in reading.reason


@pytest.mark.parametrize("value", [-0.1, 1.5])
def test_min_intent_outside_zero_one_is_refused(value):
    with pytest.raises(ValueError, match="min_intent"):
        ReaderConfig(min_intent=value)
