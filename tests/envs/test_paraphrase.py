"""Paraphrases keep the goal's attributes, use words the templates never use, replay by seed."""

import re

import numpy as np
import pytest

from vla_gr.envs.episodes import sample_episode
from vla_gr.envs.instructions import TEMPLATES, parse_instruction
from vla_gr.envs.paraphrase import SYNONYMS, paraphrase, paraphrase_episodes
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


def test_unknown_category_is_refused():
    with pytest.raises(ValueError, match="names no known category"):
        paraphrase("find the purple zebra", np.random.default_rng(0))
