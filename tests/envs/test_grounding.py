"""The world's reading of a request: which object it describes; the user's own instruction."""

import gymnasium as gym
import numpy as np
import pytest

import vla_gr.envs  # noqa: F401  (registers the id)
from vla_gr.envs import ENV_ID
from vla_gr.envs.episodes import sample_episode
from vla_gr.envs.grounding import Request, ground, read_request
from vla_gr.envs.house import generate_house
from vla_gr.envs.instructions import describe_goal, goal_candidates
from vla_gr.envs.paraphrase import VOCABULARIES, paraphrase
from vla_gr.envs.scene import House, ObjectInstance, Room
from vla_gr.geometry import GridSpec


def three_rooms() -> House:
    """Kitchen | bedroom | living room (4 m each). Chairs: red (1) in the kitchen, blue (2)
    next to a white table (3) and red (5) away from it in the bedroom; a green sofa (4) next
    to a black tv (6) in the living room."""

    def piece(i, category, color, room, x, y, half=(0.25, 0.25)):
        return ObjectInstance(i, category, color, room, x, y, 0.0, half, 0.8)

    objects = [
        piece(1, "chair", "red", 0, 1.0, 1.0),
        piece(2, "chair", "blue", 1, 5.0, 1.0),
        piece(3, "table", "white", 1, 5.8, 1.0, (0.4, 0.3)),
        piece(4, "sofa", "green", 2, 10.0, 1.0, (0.9, 0.4)),
        piece(5, "chair", "red", 1, 7.5, 3.0),
        piece(6, "tv_monitor", "black", 2, 10.0, 2.0, (0.5, 0.1)),
    ]
    rooms = [
        Room(0, "kitchen", 0.0, 0.0, 4.0, 4.0),
        Room(1, "bedroom", 4.0, 0.0, 8.0, 4.0),
        Room(2, "living_room", 8.0, 0.0, 12.0, 4.0),
    ]
    grid = GridSpec(0.0, 0.0, 0.1, 40, 120)
    empty = np.zeros(grid.shape, bool)
    return House(77, rooms, [], objects, grid, empty, np.zeros(grid.shape, np.int32))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Find the red chair in the kitchen", Request("chair", "red", "kitchen")),
        ("a couch", Request("sofa")),
        ("the chair next to the table", Request("chair", near="table")),
        ("near the telly, find the sofa", Request("sofa", near="tv_monitor")),
        ("i need you next to the settee close to the houseplant", Request("sofa", near="plant")),
        ("the chair, the red one", Request("chair", "red")),
        ("go to the chair by the white table", Request("chair", near="table", near_color="white")),
        (
            "in the lounge there is the plant that is yellow",
            Request("plant", "yellow", "living_room"),
        ),
        ("the kitchen island next to the sofa bed", Request("table", near="sofa")),
        ("the chair not far off the table", Request("chair", near="table")),
        ("Go to the fridge please", Request(None)),
    ],
)
def test_read_request(text, expected):
    assert read_request(text) == expected


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("the chair and the table", r"names two objects \(chair, table\)"),
        ("the chair in the kitchen or the bedroom", r"names two rooms \(bedroom, kitchen\)"),
        ("the red blue chair", r"gives the chair two colours \(blue, red\)"),
        ("not the red chair", "says what not to find"),
        ("the chair near the table by the sofa", r"more than one neighbour \(sofa, table\)"),
    ],
)
def test_a_request_it_cannot_read_is_one_line(text, message):
    with pytest.raises(ValueError, match=message) as err:
        read_request(text)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("text", "instance"),
    [
        ("the red chair in the kitchen", 1),
        ("a couch", 4),
        ("the chair next to the table", 2),
        ("the chair by the white table", 2),
        ("take me to the telly", 6),
        ("the red chair in the bedroom", 5),
    ],
)
def test_ground_picks_the_one_object_described(text, instance):
    assert ground(three_rooms(), text).instance.instance_id == instance


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "the red chair",
            r"'the red chair' fits 2 objects in house 77 \(red chair in the kitchen, red chair "
            r"in the bedroom\); say which",
        ),
        ("the pink chair", r"fits no object in house 77; its chairs: red chair in the kitchen, "),
        ("the lilac chair", "fits no object in house 77"),  # a colour of its own, no purple
        ("the chair by the black table", "fits no object"),
        ("go to the bed", r"asks for a bed; house 77 has none \(it has: chair, sofa, table, tv\)"),
        ("go to the fridge", r"names no object; house 77 has: chair, sofa, table, tv$"),
    ],
)
def test_no_object_or_several_is_one_line_naming_what_the_house_has(text, message):
    with pytest.raises(ValueError, match=message) as err:
        ground(three_rooms(), text)
    assert "\n" not in str(err.value)


def test_generated_and_paraphrased_instructions_ground_to_their_goal():
    """Every paraphrase vocabulary's words describe the goal the generator's words describe."""
    for k in range(0, 40, 3):
        spec = sample_episode("test", k)
        house = generate_house(spec.scene_seed)
        rng = np.random.default_rng(k)
        texts = [spec.instruction]
        texts += [paraphrase(spec.instruction, rng, v) for v in VOCABULARIES.values()]
        for text in texts:
            assert ground(house, text).instance.instance_id == spec.goal_instance_id, text


# ----------------------------------------------------------------------------- the env


def test_your_own_instruction_keeps_the_house_and_start_and_grounds_the_goal():
    env = gym.make(ENV_ID, split="val", image_size=32)
    u = env.unwrapped
    try:
        env.reset(options={"episode": 5})
        before = u.episode_spec
        other = next(i for i in goal_candidates(u.house) if i != before.goal_instance_id)
        text = describe_goal(u.house, other, np.random.default_rng(1)).upper()
        obs, info = env.reset(options={"episode": 5, "instruction": text})
        spec = u.episode_spec
        assert u.goal.instance_id == spec.goal_instance_id == other
        assert obs["instruction"] == text and spec.instruction == text
        assert (spec.scene_seed, spec.start_x, spec.start_y, spec.start_yaw) == (
            before.scene_seed,
            before.start_x,
            before.start_y,
            before.start_yaw,
        )
        assert info["episode_id"] == before.episode_id
        assert info["distance_to_goal"] == pytest.approx(spec.geodesic_start_distance)
        assert spec.geodesic_start_distance != pytest.approx(before.geodesic_start_distance)
        assert spec.description == read_request(text).fields
        assert spec.description["category"] == u.goal.category
        with pytest.raises(ValueError, match=r"fits \d+ objects in house") as err:
            env.reset(options={"episode": 5, "instruction": f"find the {u.goal.category}"})
        assert "\n" not in str(err.value)
        with pytest.raises(RuntimeError, match="before reset"):  # the failed reset ended it
            env.step(np.zeros(3, np.float32))
        obs, _ = env.reset(options={"episode": 5})  # and episode 5 is itself again
        assert u.episode_spec == before and obs["instruction"] == before.instruction
    finally:
        env.close()
