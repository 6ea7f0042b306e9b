"""The object-category segmenter and S2's object check: shapes, the match on a goal mask
against hand-computed means, and which category an instruction names."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vla_gr.agent.perception import (
    ObjectCategoryConfig,
    ObjectCategorySegmenter,
    category_match,
    instructed_anchor,
    instructed_category,
)
from vla_gr.configs.model_schema import ModelConfig

CATEGORIES = ["chair", "sofa", "bed", "toilet", "tv_monitor", "plant", "table", "cabinet"]


def test_segmenter_gives_per_pixel_probabilities_at_the_input_size():
    torch.manual_seed(0)
    seg = ObjectCategorySegmenter(ObjectCategoryConfig(channels=[8, 16, 16]))
    rgb = torch.randint(0, 256, (2, 3, 64, 48), dtype=torch.uint8)
    depth = torch.rand(2, 1, 64, 48) * 5.0
    logits = seg(rgb, depth)
    assert logits.shape == (2, 1 + len(CATEGORIES), 64, 48)
    probs = seg.probabilities(rgb, depth)
    assert torch.allclose(probs.sum(1), torch.ones(2, 64, 48), atol=1e-5)
    # each frame is segmented on its own: a batch of two equals the frames one by one
    assert torch.allclose(seg(rgb[1:], depth[1:]), logits[1:], atol=1e-5)
    with pytest.raises(ValueError, match="depth must be"):
        seg(rgb, depth[:, :, :32])


def test_category_match_is_the_mean_probability_over_the_goal_pixels():
    probs = np.zeros((3, 4, 4), np.float32)  # background, chair, sofa
    probs[0] = 1.0
    probs[:, 0, :2] = [[0.1], [0.7], [0.2]]  # two pixels: chair 0.7
    probs[:, 1, :1] = [[0.0], [0.1], [0.9]]  # one pixel: sofa 0.9
    goal = np.zeros((4, 4), bool)
    goal[0, :2] = goal[1, 0] = True
    assert category_match(probs, goal, 1) == pytest.approx((0.7 + 0.7 + 0.1) / 3)
    assert category_match(probs, goal, 2) == pytest.approx((0.2 + 0.2 + 0.9) / 3)
    assert category_match(probs, goal, 1, min_pixels=4) is None  # too few: no evidence
    assert category_match(probs, np.zeros((4, 4), bool), 1) is None
    with pytest.raises(ValueError, match="differ in size"):
        category_match(probs, np.ones((3, 3), bool), 1)


@pytest.mark.parametrize(
    "instruction, category",
    [
        ("Find the red chair in the kitchen", "chair"),
        ("Go to the tv next to the sofa", "tv_monitor"),
        ("Take me to the plant by the cabinet", "plant"),  # the anchor after "by" is not it
        ("Could you bring me to the sofa near the tv?", "sofa"),
        ("locate the BED", "bed"),
        ("find the couch", None),  # a synonym outside the categories: the check stays off
        ("next to the chair, find the television", None),  # only an anchor is named
        ("go to the chairs", None),  # whole words only
    ],
)
def test_instructed_category_reads_the_goal_not_the_relation_anchor(instruction, category):
    expected = None if category is None else CATEGORIES.index(category) + 1
    assert instructed_category(instruction, CATEGORIES) == expected


@pytest.mark.parametrize(
    "instruction, anchor",
    [
        ("Find the chair near the plant", "plant"),
        ("Go to the purple sofa by the tv", "tv_monitor"),
        ("can you go to the orange chair beside the sofa?", "sofa"),
        ("Move to the chair next to the cabinet in the kitchen", "cabinet"),
        ("find the red chair in the kitchen", None),  # no relation
        ("find the chair near the window", None),  # an anchor outside the categories
        ("find the chair near the lamp by the bed", None),  # only the first relation counts
    ],
)
def test_instructed_anchor_reads_the_category_right_after_the_relation(instruction, anchor):
    expected = None if anchor is None else CATEGORIES.index(anchor) + 1
    assert instructed_anchor(instruction, CATEGORIES) == expected


def test_bad_settings_name_the_key():
    with pytest.raises(ValueError, match="model.object_category.categories"):
        ObjectCategoryConfig(categories=["chair", "chair"])
    with pytest.raises(ValueError, match="model.object_category.channels"):
        ObjectCategoryConfig(channels=[8])
    with pytest.raises(ValueError, match="model.object_category.enabled=true needs"):
        ModelConfig(agent="end_to_end", object_category=ObjectCategoryConfig(enabled=True))
    with pytest.raises(TypeError, match="instruction must be a str"):
        instructed_category(None, CATEGORIES)
