"""The room check's parts: which room an instruction names, and the room-type classifier."""

import numpy as np
import pytest
import torch

from vla_gr.agent.perception import RoomTypeClassifier, RoomTypeConfig, instructed_room
from vla_gr.configs import ConfigError, load_config
from vla_gr.envs.episodes import sample_episode
from vla_gr.envs.instructions import parse_instruction
from vla_gr.envs.paraphrase import HELD_OUT, paraphrase
from vla_gr.envs.scene import ROOM_TYPES

ROOMS = RoomTypeConfig().room_types


def test_the_classifier_predicts_the_world_s_room_types():
    assert tuple(ROOMS) == ROOM_TYPES


def test_instructed_room_agrees_with_the_world_s_parse_on_generated_instructions():
    seen = set()
    for index in range(60):
        try:
            text = sample_episode("train", 50_000 + index).instruction
        except ValueError:  # a house without a goal candidate
            continue
        room = parse_instruction(text)["room"]
        got = instructed_room(text, ROOMS)
        assert (None if got is None else ROOMS[got]) == room, text
        seen.add(room)
    assert None in seen and len(seen) >= 3  # instructions with and without rooms were checked


@pytest.mark.parametrize(
    "text, room",
    [
        ("Find the red chair in the Living Room", "living_room"),
        ("go to the plant in the bedroom", "bedroom"),  # not "bed"
        ("Find the chair", None),
        ("go into the kitchen and find the seat", None),  # not "in the <room>"
        ("find the sofa in the lounge", None),  # a room word outside room_types
        ("", None),
    ],
)
def test_instructed_room_reads_in_the_room_only(text, room):
    got = instructed_room(text, ROOMS)
    assert (None if got is None else ROOMS[got]) == room


def test_held_out_room_words_switch_the_check_off_rather_than_guess():
    rng = np.random.default_rng(0)
    for _ in range(40):
        text = paraphrase("Find the chair in the living room", rng, HELD_OUT)
        got = instructed_room(text, ROOMS)
        assert got is None or ROOMS[got] == "living_room", text


def test_instructed_room_refuses_non_text():
    with pytest.raises(TypeError, match="instruction must be a str"):
        instructed_room(None, ROOMS)


def test_classifier_outputs_a_distribution_and_reads_uint8_like_unit_floats():
    torch.manual_seed(0)
    net = RoomTypeClassifier(RoomTypeConfig(channels=[8, 16]))
    rgb = torch.randint(0, 256, (3, 3, 32, 32), dtype=torch.uint8)
    depth = torch.rand(3, 1, 32, 32) * 12.0  # beyond max_depth is clipped
    logits = net(rgb, depth)
    assert logits.shape == (3, len(ROOMS))
    torch.testing.assert_close(net(rgb.float() / 255.0, depth), logits)
    probs = net.probabilities(rgb, depth)
    torch.testing.assert_close(probs.sum(-1), torch.ones(3))
    with pytest.raises(ValueError, match="rgb must be"):
        net(rgb[:, :2], depth)
    with pytest.raises(ValueError, match="depth must be"):
        net(rgb, depth[:2])


def test_classifier_depends_on_the_whole_frame_not_on_the_batch():
    torch.manual_seed(0)
    net = RoomTypeClassifier(RoomTypeConfig(channels=[8, 16])).eval()
    rgb = torch.randint(0, 256, (4, 3, 32, 32), dtype=torch.uint8)
    depth = torch.rand(4, 1, 32, 32) * 5.0
    together = net(rgb, depth)
    alone = torch.cat([net(rgb[i : i + 1], depth[i : i + 1]) for i in range(4)])
    torch.testing.assert_close(together, alone)
    changed = rgb.clone()
    changed[0, :, :16] = 255 - changed[0, :, :16]  # the top half of frame 0 only
    after = net(changed, depth)
    assert not torch.allclose(after[0], together[0]) and torch.equal(after[1:], together[1:])


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["model.room_type.room_types=[kitchen]"], "at least two distinct"),
        (["model.room_type.room_types=[kitchen,kitchen]"], "at least two distinct"),
        (["model.room_type.channels=[]"], "model.room_type.channels"),
        (["model.agent=end_to_end", "model.room_type.enabled=true"], "needs model.agent"),
    ],
)
def test_bad_room_type_settings_name_the_key(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config("config_debug", ["model.agent=dual_system", *overrides])


def test_a_larger_frame_is_read_as_its_area_average_at_input_size():
    torch.manual_seed(0)
    net = RoomTypeClassifier(RoomTypeConfig(channels=[8, 16], input_size=16)).eval()
    rgb = torch.rand(2, 3, 32, 32)
    depth = torch.rand(2, 1, 32, 32) * 5.0
    pooled = (
        torch.nn.functional.avg_pool2d(rgb, 2),
        torch.nn.functional.avg_pool2d(depth, 2),
    )  # depth below max_depth: clipping and averaging commute
    torch.testing.assert_close(net(rgb, depth), net(*pooled))
