"""Paraphrases keep the goal's attributes, use words the templates never use, replay by seed."""

import itertools
import re

import numpy as np
import pytest
import torch

from vla_gr.envs.episodes import sample_episode
from vla_gr.envs.instructions import TEMPLATES, parse_instruction
from vla_gr.envs.nav_env import INSTRUCTION_MAX_LENGTH
from vla_gr.envs.paraphrase import (
    HELD_OUT,
    SYNONYMS,
    TRAINING,
    VALIDATION,
    VOCABULARIES,
    paraphrase,
    paraphrase_episodes,
    paraphrase_instructions,
)
from vla_gr.envs.scene import category_display_name

SPECS = [sample_episode("test", i) for i in range(40)]


def test_paraphrases_keep_colour_room_and_neighbour_but_not_the_category_word():
    rng = np.random.default_rng(0)
    template_words = set(re.findall(r"[a-z']+", " ".join(TEMPLATES).replace("{np}", "")))
    for spec in SPECS:
        parts = parse_instruction(spec.instruction)
        text = paraphrase(spec.instruction, rng)
        words = set(re.findall(r"[a-z']+", text))
        assert category_display_name(parts["category"]) not in words, text
        assert any(syn in text for syn in SYNONYMS[parts["category"]]), text
        if parts["color"]:
            assert f"that is {parts['color']}" in text, text
        if parts["room"]:
            room = parts["room"].replace("_", " ")
            assert room in text or {"living room": "lounge", "hallway": "corridor",
                                    "office": "study"}.get(room, "?") in text, text  # fmt: skip
        if parts["near"]:
            assert any(syn in text for syn in SYNONYMS[parts["near"]]), text
        assert not text.startswith(tuple(t.split("{")[0] for t in TEMPLATES)), text
        assert words - template_words  # words of its own


def test_paraphrase_episodes_changes_only_the_instruction_and_replays():
    a, b = paraphrase_episodes(SPECS[:5], seed=1), paraphrase_episodes(SPECS[:5], seed=1)
    assert a == b
    for old, new in zip(SPECS[:5], a):
        assert new.instruction != old.instruction
        assert new.to_dict() | {"instruction": old.instruction} == old.to_dict()
    for old, new in zip(SPECS[:5], paraphrase_episodes(SPECS[:5], 1, VALIDATION)):
        words = VALIDATION.synonyms[parse_instruction(old.instruction)["category"]]
        assert any(w in new.instruction for w in words), new.instruction


def test_unknown_category_is_refused():
    with pytest.raises(ValueError, match="names no known category"):
        paraphrase("find the purple zebra", np.random.default_rng(0))


def _vocabulary_words(v) -> set[str]:
    """Every word a vocabulary adds (synonyms, room words, near phrases, shapes' own words)."""
    text = " ".join(
        [
            *(w for ws in v.synonyms.values() for w in ws),
            *v.room_words.values(),
            *v.near_words,
            v.color_subject,
            *v.room_shapes,
            *v.plain_shapes,
        ]  # fmt: skip
    )
    return set(re.findall(r"[a-z']+", text.replace("{", " {").replace("}", "} ")))


@pytest.mark.parametrize(
    "first, second",
    [(VOCABULARIES[a], VOCABULARIES[b]) for a, b in itertools.combinations(VOCABULARIES, 2)],
    ids=[f"{a}-{b}" for a, b in itertools.combinations(VOCABULARIES, 2)],
)
def test_the_vocabularies_share_no_word(first, second):
    template_words = set(re.findall(r"[a-z']+", " ".join(TEMPLATES).replace("{np}", "")))
    slots = {"subject", "room", "noun", "color", "in", "is", "a"}  # slots and function words
    shared = (_vocabulary_words(first) & _vocabulary_words(second)) - template_words - slots
    assert not shared, shared
    assert first.synonyms.keys() == second.synonyms.keys()


def test_training_paraphrases_use_training_words_only():
    template_words = set(re.findall(r"[a-z']+", " ".join(TEMPLATES).replace("{np}", "")))
    slots = {"subject", "room", "noun", "color", "in", "is"}  # slots and function words
    rng = np.random.default_rng(0)
    held_out_words = _vocabulary_words(HELD_OUT) - template_words - slots
    for spec in SPECS:
        text = paraphrase(spec.instruction, rng, TRAINING)
        assert not set(re.findall(r"[a-z']+", text)) & held_out_words, text
        parts = parse_instruction(spec.instruction)
        assert any(syn in text for syn in TRAINING.synonyms[parts["category"]]), text


def test_training_rewrites_follow_the_probability_and_torchs_seed():
    texts = [s.instruction for s in SPECS] + ["find the purple zebra"]
    assert paraphrase_instructions(texts, 0.0) == texts
    torch.manual_seed(3)
    a = paraphrase_instructions(texts, 1.0)
    torch.manual_seed(3)
    assert paraphrase_instructions(texts, 1.0) == a  # replays from torch's RNG state
    assert a[-1] == texts[-1]  # no known category: kept
    assert all(new != old for new, old in zip(a[:-1], texts[:-1]))
    torch.manual_seed(0)
    half = paraphrase_instructions(texts[:-1], 0.5)
    changed = sum(new != old for new, old in zip(half, texts[:-1]))
    assert 8 <= changed <= 32  # 40 draws at p = 0.5


@pytest.mark.parametrize("name", sorted(VOCABULARIES))
def test_every_vocabulary_writes_episodes_the_env_accepts(name):
    # the env refuses an instruction that is not printable ASCII (NavEnv._start_episode)
    for spec in paraphrase_episodes(SPECS[:40], seed=0, vocabulary=VOCABULARIES[name]):
        text = spec.instruction
        assert text.isascii() and text.isprintable(), text
        assert len(text) <= INSTRUCTION_MAX_LENGTH, text
