"""Instructions: they match the goal, identify it uniquely, and vary in phrasing."""

from collections import Counter
from functools import cache

import numpy as np
import pytest

from vla_gr.envs.house import build_house, generate_house
from vla_gr.envs.instructions import (
    TEMPLATES,
    Description,
    describe_goal,
    distractors,
    goal_candidates,
    matches,
    neighbour_categories,
    parse_instruction,
    polygon_gap,
)
from vla_gr.envs.scene import GOAL_CATEGORIES, ObjectInstance, Room


@cache
def house(seed: int):
    return generate_house(seed)


def square(x, y, half=0.5):
    return np.array(
        [[x - half, y - half], [x + half, y - half], [x + half, y + half], [x - half, y + half]]
    )


def test_polygon_gap_analytic():
    assert polygon_gap(square(0, 0), square(3, 0)) == pytest.approx(2.0)
    assert polygon_gap(square(0, 0), square(3, 4)) == pytest.approx(np.hypot(2, 3))
    assert polygon_gap(square(0, 0), square(0.5, 0.5)) == 0.0


def test_parse_examples():
    p = parse_instruction("Navigate to the blue sofa next to the tv")
    assert p == {"category": "sofa", "color": "blue", "room": None, "near": "tv_monitor"}
    p = parse_instruction("go to the plant in the bedroom")
    assert p == {"category": "plant", "color": None, "room": "bedroom", "near": None}
    p = parse_instruction("Can you go to the red bed in the living room?")
    assert p == {"category": "bed", "color": "red", "room": "living_room", "near": None}
    with pytest.raises(ValueError, match="text"):
        parse_instruction(3)


def test_instructions_name_the_goal_uniquely_and_distractors_exist():
    rng = np.random.default_rng(0)
    intents, openings, cats = Counter(), Counter(), Counter()
    for seed in range(10):
        h = house(seed)
        candidates = goal_candidates(h)
        assert candidates, seed
        for goal_id in candidates:
            goal = h.object(goal_id)
            assert goal.category in GOAL_CATEGORIES
            rivals = [h.object(i) for i in distractors(h, goal_id)]
            assert rivals and all(r.category == goal.category for r in rivals)
            for _ in range(3):
                text = describe_goal(h, goal_id, rng)
                p = parse_instruction(text)
                assert p["category"] == goal.category, text
                assert p["color"] or p["room"] or p["near"], text
                if p["color"]:
                    assert p["color"] == goal.color, text
                if p["room"]:
                    assert p["room"] == h.rooms[goal.room_index].room_type, text
                if p["near"]:
                    assert p["near"] in neighbour_categories(h, goal), text
                desc = Description(p["category"], p["color"], p["room"], p["near"])
                assert matches(h, goal, desc)
                assert not any(matches(h, r, desc) for r in rivals), text
                intents[desc.intent] += 1
                openings[" ".join(text.lower().split()[:2])] += 1
            cats[goal.category] += 1
    assert len(intents) >= 4 and {"color", "room", "color+room"} <= set(intents)
    assert len(openings) >= 8  # many distinct phrasings
    assert len(cats) >= 4


def test_same_rng_same_instruction():
    h = house(1)
    goal = goal_candidates(h)[0]
    a = [describe_goal(h, goal, np.random.default_rng(5)) for _ in range(2)]
    assert a[0] == a[1]
    texts = {describe_goal(h, goal, np.random.default_rng(k)) for k in range(40)}
    assert len(texts) >= 5


def _two_chairs(color_b: str, room_b: int):
    rooms = [Room(0, "kitchen", 0.0, 0.0, 4.0, 4.0), Room(1, "bedroom", 4.1, 0.0, 8.0, 4.0)]
    objects = [
        ObjectInstance(1, "chair", "white", 0, 0.5, 0.5, 0.0, (0.22, 0.22), 0.9),
        ObjectInstance(
            2, "chair", color_b, room_b, 3.5 if room_b == 0 else 7.5, 3.5, 0.0, (0.22, 0.22), 0.9
        ),
        ObjectInstance(3, "table", "black", 0, 0.5, 1.4, 0.0, (0.5, 0.4), 0.75),
    ]
    return build_house(seed=0, rooms=rooms, doors=[], objects=objects)


def test_indistinguishable_goal_is_refused_and_relations_disambiguate():
    h = _two_chairs("white", 0)  # same colour, same room; only chair 1 is next to the table
    assert goal_candidates(h) == [1]
    text = describe_goal(h, 1, np.random.default_rng(0))
    assert parse_instruction(text)["near"] == "table"
    with pytest.raises(ValueError, match="no unique description"):
        describe_goal(h, 2, np.random.default_rng(0))


def test_room_and_colour_disambiguate():
    h = _two_chairs("white", 1)  # same colour, other room
    texts = {describe_goal(h, 2, np.random.default_rng(k)) for k in range(30)}
    assert all(parse_instruction(t)["room"] == "bedroom" for t in texts)
    h = _two_chairs("red", 0)  # other colour, same room
    texts = {describe_goal(h, 2, np.random.default_rng(k)) for k in range(30)}
    assert all(parse_instruction(t)["color"] == "red" for t in texts)
    assert len(TEMPLATES) >= 8
