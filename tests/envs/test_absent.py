"""Absent-object episodes: deterministic, really absent, written only when set, and run by the
world without a goal (no STOP succeeds, "not found" ends them)."""

import dataclasses
import json

import gymnasium as gym
import numpy as np
import pytest

import vla_gr.envs  # noqa: F401  (registers the id)
from vla_gr.envs import ENV_ID
from vla_gr.envs.absent import (
    ABSENT_GOAL_ID,
    absent_descriptions,
    check_absent,
    fitting_objects,
    requested_object,
    sample_absent_episode,
)
from vla_gr.envs.episodes import (
    EpisodeFileError,
    EpisodeSpec,
    load_episodes,
    sample_episode,
    save_episodes,
)
from vla_gr.envs.geodesic import traversable_cells
from vla_gr.envs.grounding import ground, read_request
from vla_gr.envs.house import generate_house
from vla_gr.envs.instructions import parse_instruction
from vla_gr.envs.scene import GOAL_CATEGORIES

from .test_episodes import box_room_house

INDICES = range(24)


@pytest.fixture(scope="module")
def absent_specs():
    return [sample_absent_episode("val", i, num_rooms=1 + i % 6) for i in INDICES]


def test_absent_episodes_are_deterministic_and_differ_from_the_normal_twin(absent_specs):
    again = [sample_absent_episode("val", i, num_rooms=1 + i % 6) for i in INDICES]
    assert again == absent_specs
    for i, spec in zip(INDICES, absent_specs):
        twin = sample_episode("val", i, num_rooms=1 + i % 6)
        assert spec.scene_seed == twin.scene_seed and spec.episode_id == f"val-{i:06d}-absent"
        assert spec.absent and spec.goal_instance_id == ABSENT_GOAL_ID
        assert spec.geodesic_start_distance == 0.0 and spec.description is None
    other_split = sample_absent_episode("test", 0, num_rooms=1)
    assert other_split.scene_seed != absent_specs[0].scene_seed


def test_no_object_of_the_house_fits_an_absent_request(absent_specs):
    kinds = set()
    for spec in absent_specs:
        house = generate_house(spec.scene_seed, spec.num_rooms, clutter=spec.clutter)
        said = parse_instruction(spec.instruction)  # the generator's words, read back
        assert said["category"] == spec.goal_category in GOAL_CATEGORIES
        same = [o for o in house.objects if o.category == said["category"]]
        assert not [o for o in same if said["color"] in (None, o.color)]  # nothing fits
        kinds.add("colour" if same else "category")
        assert (said["color"] is not None) == bool(same)
        assert fitting_objects(house, spec) == []
        with pytest.raises(ValueError, match="has none|fits no object"):
            ground(house, spec.instruction)  # the world's reading finds no such object
        row, col = house.grid.world_to_cell(spec.start_pose[:2])
        assert traversable_cells(house)[row, col]
    assert kinds == {"colour", "category"}  # both kinds are drawn


def test_absent_descriptions_name_only_what_the_house_lacks():
    house = box_room_house()  # a red chair and a blue table
    options = absent_descriptions(house)
    colours = {d.color for d in options["colour"]}
    assert {d.category for d in options["colour"]} == {"chair"}  # the table is no goal category
    assert "red" not in colours and len(colours) == 7
    assert {d.category for d in options["category"]} == set(GOAL_CATEGORIES) - {"chair"}


def _absent_box_spec(**kw) -> EpisodeSpec:
    fields = dict(
        episode_id="room-absent", split="val", scene_seed=5, num_rooms=1, clutter=1.0,
        start_x=1.0, start_y=1.0, start_yaw=0.0, goal_instance_id=ABSENT_GOAL_ID,
        goal_category="chair", instruction="find the green chair", geodesic_start_distance=0.0,
        absent=True,
    )  # fmt: skip
    fields.update(kw)
    return EpisodeSpec(**fields)


def test_an_absent_spec_round_trips_and_a_spec_without_it_is_written_as_before(tmp_path):
    absent = _absent_box_spec()
    normal = dataclasses.replace(absent, absent=False, goal_instance_id=3, instruction="find it")
    assert absent.to_dict()["absent"] is True and "absent" not in normal.to_dict()
    path = save_episodes(tmp_path / "mixed.jsonl", [absent, normal])
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    assert lines[0]["absent"] is True and "absent" not in lines[1]
    assert load_episodes(path, check=False) == [absent, normal]
    assert EpisodeSpec.from_dict(dict(normal.to_dict(), absent=False)) == normal
    with pytest.raises(ValueError, match="absent must be true or false"):
        _absent_box_spec(absent="yes")


def test_an_absent_request_that_fits_an_object_is_refused_naming_it(tmp_path):
    house = box_room_house()
    check_absent(_absent_box_spec(), house)
    with pytest.raises(ValueError, match=r"fits the red chair .*\(object 3\)"):
        check_absent(_absent_box_spec(instruction="find the red chair"), house)
    with pytest.raises(ValueError, match="goal_instance_id=-1 and geodesic_start_distance=0"):
        check_absent(_absent_box_spec(goal_instance_id=3), house)
    spec = sample_absent_episode("val", 0, num_rooms=1)
    house = generate_house(spec.scene_seed, 1)
    present = next(o for o in house.objects if o.category in GOAL_CATEGORIES)
    lying = dataclasses.replace(
        spec,
        goal_category=present.category,
        instruction=f"find the {present.color} {present.category}",
    )
    path = save_episodes(tmp_path / "lying.jsonl", [spec, lying])
    with pytest.raises(EpisodeFileError, match=r"lying.jsonl:2: .*absent-object request"):
        load_episodes(path)  # checked when the file is loaded
    assert requested_object(spec)["instance_id"] == ABSENT_GOAL_ID
    assert requested_object(spec)["color"] == read_request(spec.instruction).color


def test_the_world_runs_an_absent_episode_without_a_goal():
    env = gym.make(ENV_ID, image_size=32)
    try:
        obs, info = env.reset(options={"episode": _absent_box_spec(), "house": box_room_house()})
        u = env.unwrapped
        assert u.goal is None and u.goal_id is None and info["distance_to_goal"] == np.inf
        assert (
            info["geodesic_start_distance"] == 0.0 and obs["instruction"] == "find the green chair"
        )
        _, reward, terminated, _, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
        assert terminated and reward == 0.0 and info["success"] == 0.0 and info["spl"] == 0.0
        env.reset(options={"episode": _absent_box_spec(), "house": box_room_house()})
        _, _, terminated, _, info = u.declare("not_found")
        assert terminated and info["declared"] == "not_found" and info["success"] == 0.0
        # the user's own words name an object of the house: a normal episode again
        _, info = env.reset(options={"episode": _absent_box_spec(), "house": box_room_house(),
                                     "instruction": "find the red chair"})  # fmt: skip
        assert (
            not u.episode_spec.absent and u.goal_id == 3 and np.isfinite(info["distance_to_goal"])
        )
    finally:
        env.close()
