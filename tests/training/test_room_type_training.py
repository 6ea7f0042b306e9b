"""The room-type stage: frames labelled with the room the robot stands in, and a trained
classifier written into the agent with the rest of it untouched."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from vla_gr.checkpoint import read_checkpoint
from vla_gr.cli import main
from vla_gr.data.store import EpisodeStore
from vla_gr.envs.episodes import EpisodeSpec
from vla_gr.envs.house import generate_house
from vla_gr.errors import UserError
from vla_gr.policy import VLAGRPolicy
from vla_gr.training.agent_stage import build_agent_from, graft_part, write_agent
from vla_gr.training.room_type import frame_rooms, room_accuracy, room_frames, train_room_type

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"
ROOMS = ["kitchen", "living_room", "bedroom", "bathroom", "office", "hallway"]


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    """The shipped agent without a room-type classifier (whether or not it ships one)."""
    out = tmp_path_factory.mktemp("plain") / "agent"
    policy, loaded, config = build_agent_from(
        SHIPPED, "room_type", [], keep_part=False, forced=["room_type.enabled=false"]
    )
    assert policy.room_type is None
    return write_agent(policy, loaded, config, out, {})


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """Expert episodes 2-5 of `train` (two houses) at 32 px."""
    path = tmp_path_factory.mktemp("rooms") / "store.zarr"
    args = ["collect", "--config-name", "config_debug", f"collect.output={path}",
            "collect.split=train", "collect.first_episode=2", "collect.num_episodes=4"]  # fmt: skip
    assert main(args) == 0
    return path


def test_labels_are_the_room_of_the_start_and_of_the_goal_at_the_end(store):
    s = EpisodeStore.open(store)
    for e in range(s.num_episodes):
        spec = EpisodeSpec.from_dict(s.spec(e))
        house = generate_house(spec.scene_seed, num_rooms=spec.num_rooms, clutter=spec.clutter)
        labels = frame_rooms(s.spec(e), s.episode(e, ["pose"])["pose"], ROOMS, {})
        start_room = house.room_of(spec.start_x, spec.start_y).room_type
        goal = house.object(spec.goal_instance_id)
        assert ROOMS[labels[0]] == start_room  # the stored pose starts at (0, 0, 0)
        # the expert stops beside the goal, in its room: the relative poses were rotated back
        assert ROOMS[labels[-1]] == house.rooms[goal.room_index].room_type
        assert len(set(labels.tolist())) >= 1 and (labels >= -1).all()


def test_room_frames_keeps_every_stride_th_labelled_frame(store):
    s = EpisodeStore.open(store)
    frames = room_frames(store, ROOMS, stride=3)
    expected, houses = 0, {}
    for e in range(s.num_episodes):
        labels = frame_rooms(s.spec(e), s.episode(e, ["pose"])["pose"], ROOMS, houses)
        expected += int((labels[::3] >= 0).sum())
    assert len(frames["label"]) == expected > 0
    assert frames["rgb"].shape == (expected, 3, 32, 32) and frames["rgb"].dtype == np.uint8
    assert frames["depth"].shape == (expected, 1, 32, 32)
    assert len(np.unique(frames["house"])) == 2
    with pytest.raises(UserError, match="selects none"):
        room_frames(store, ROOMS, first=4)


def test_trained_classifier_is_written_with_the_room_check_and_the_rest_untouched(
    store, plain, tmp_path
):
    frames = room_frames(store, ROOMS, stride=2)
    out = tmp_path / "agent"
    summary = train_room_type(plain, out, frames, ROOMS, steps=4, batch_size=16,
                              eval_every=2, reject_threshold=0.3, eval_frames=frames)  # fmt: skip
    assert [row["step"] for row in summary["history"]] == [2, 4]
    assert summary["best_val_accuracy"] == max(r["accuracy"] for r in summary["history"])
    assert summary["eval"]["frames"] == len(frames["label"])
    written = read_checkpoint(out)
    model = OmegaConf.create(written.config_yaml).model
    assert model.room_type.enabled and model.navigator.goal_checks.room_reject_threshold == 0.3
    init = read_checkpoint(plain).model
    for name, value in init.items():
        assert torch.equal(written.model[name], value), name  # the rest bit for bit
    assert {k for k in written.model if k not in init} == {
        k for k in written.model if k.startswith("room_type.")
    }
    policy = VLAGRPolicy.from_pretrained(out)
    assert policy.room_type is not None
    # the loaded classifier is the one that was evaluated
    assert room_accuracy(policy.room_type, frames) == summary["eval"]
    obs = {
        "rgb": frames["rgb"][0].transpose(1, 2, 0),
        "depth": frames["depth"][0].transpose(1, 2, 0),
        "pose": np.zeros(3, np.float32),
    }

    def room_match(policy, obs: dict) -> float:
        return policy.perception.perceive(obs).room_match

    assert room_match(policy, {**obs, "instruction": "find the chair"}) == 1.0
    probs = policy.room_type.probabilities(
        torch.from_numpy(frames["rgb"][:1]), torch.from_numpy(frames["depth"][:1])
    )[0]
    kitchen = room_match(policy, {**obs, "instruction": "find the chair in the kitchen"})
    assert kitchen == pytest.approx(float(probs[0]))
    # an agent without the classifier passes every room
    kitchen_obs = {**obs, "instruction": "find the chair in the kitchen"}
    assert room_match(VLAGRPolicy.from_pretrained(plain), kitchen_obs) == 1.0
    # the classifier grafted onto an agent (a graft stage): its weights, the rest the agent's
    grafted = tmp_path / "grafted"
    graft_part(
        plain, out, "room_type", grafted, ["navigator.goal_checks.room_reject_threshold=0.4"]
    )
    again = read_checkpoint(grafted)
    assert again.model.keys() == written.model.keys()
    for name, value in written.model.items():
        assert torch.equal(again.model[name], value), name
    model = OmegaConf.create(again.config_yaml).model
    assert model.room_type.enabled and model.navigator.goal_checks.room_reject_threshold == 0.4
    with pytest.raises(UserError, match="holds no room_type weights"):
        graft_part(plain, plain, "room_type", tmp_path / "no")  # a donor without one


def test_frames_labelled_in_other_room_types_are_refused(store, plain, tmp_path):
    frames = room_frames(store, ROOMS, stride=4)
    with pytest.raises(UserError, match="frames are labelled in"):
        train_room_type(plain, tmp_path / "x", frames, ROOMS[::-1], steps=1)
