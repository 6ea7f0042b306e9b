"""Episode specs: start sampling, validation reasons, JSONL round trip, determinism."""

import dataclasses
import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest

from vla_gr.envs.episodes import (
    MAX_START_DISTANCE,
    MIN_START_DISTANCE,
    OPTIONAL_FIELDS,
    EpisodeFileError,
    EpisodeSpec,
    episode_rng,
    goal_field,
    load_episodes,
    sample_start,
    save_episodes,
    validate_spec,
)
from vla_gr.envs.geodesic import sample_field, traversable_cells
from vla_gr.envs.scene import House, ObjectInstance, Room
from vla_gr.geometry import GridSpec

# ----------------------------------------------------------------------------- helpers


def box_room_house(seed: int = 5, cell: float = 0.05) -> House:
    """One 6 x 4 m room (interior x in [0.1, 6.1], y in [0.1, 4.1]) with 0.1 m walls.

    A red chair (id 3) of footprint 0.5 x 0.5 m at (5.0, 2.0), a walled-off closet in the
    corner x > 5.3, y > 3.3 (free inside, unreachable), and a blue table (id 4) at (1.5, 3.2).
    """
    grid = GridSpec(0.0, 0.0, cell, int(round(4.2 / cell)), int(round(6.2 / cell)))
    xs, ys = grid.cell_centres()  # (H, W) each
    occ = (xs < 0.1) | (xs > 6.1) | (ys < 0.1) | (ys > 4.1)
    # Closet walls: a 0.1 m thick L around [5.3, 6.1] x [3.3, 4.1].
    occ |= (np.abs(xs - 5.25) < 0.05) & (ys > 3.2)
    occ |= (np.abs(ys - 3.25) < 0.05) & (xs > 5.2)
    chair = ObjectInstance(3, "chair", "red", 0, 5.0, 2.0, 0.0, (0.25, 0.25), 0.9)
    table = ObjectInstance(4, "table", "blue", 0, 1.5, 3.2, 0.0, (0.4, 0.3), 0.75)
    ids = np.zeros(grid.shape, np.int32)
    for obj in (chair, table):
        hx, hy = obj.half_extents
        ids[(np.abs(xs - obj.x) <= hx) & (np.abs(ys - obj.y) <= hy)] = obj.instance_id
    occ |= ids > 0
    rooms = [Room(0, "living_room", 0.1, 0.1, 6.1, 4.1)]
    return House(seed, rooms, [], [chair, table], grid, occ, ids)


def make_spec(house: House, x: float, y: float, yaw: float = 0.0, goal: int = 3, **kw):
    fields = dict(
        episode_id="val-000001",
        split="val",
        scene_seed=house.seed,
        num_rooms=1,
        clutter=1.0,
        start_x=x,
        start_y=y,
        start_yaw=yaw,
        goal_instance_id=goal,
        goal_category=house.object(goal).category if goal in (3, 4) else "chair",
        instruction="find the red chair",
        geodesic_start_distance=0.0,
    )
    fields.update(kw)
    return EpisodeSpec(**fields)


# ----------------------------------------------------------------------------- sampling


def test_sample_start_within_band_and_reachable():
    house = box_room_house()
    field = goal_field(house, 3)  # (H, W)
    trav = traversable_cells(house)
    for i in range(20):
        x, y, yaw, dist = sample_start(house, field, np.random.default_rng(i))
        assert MIN_START_DISTANCE <= dist <= MAX_START_DISTANCE
        assert -math.pi <= yaw <= math.pi
        r, c = house.grid.world_to_cell(np.array([x, y]))
        assert trav[r, c] and np.isfinite(field[r, c])
        assert not (x > 5.3 and y > 3.3)  # never in the sealed closet
        assert dist == pytest.approx(sample_field(field, house.grid, x, y), abs=1e-9)
        assert validate_spec(make_spec(house, x, y, yaw), house) == pytest.approx(dist)


def test_sample_start_none_when_band_empty():
    house = box_room_house()
    field = goal_field(house, 3)
    assert sample_start(house, field, np.random.default_rng(0), 20.0, 30.0) is None


def test_episode_rng_deterministic_and_independent():
    a = episode_rng("val", 7).random(4)
    np.testing.assert_array_equal(a, episode_rng("val", 7).random(4))
    assert not np.allclose(a, episode_rng("val", 8).random(4))
    assert not np.allclose(a, episode_rng("train", 7).random(4))
    with pytest.raises(ValueError, match="split"):
        episode_rng("dev", 0)


# ----------------------------------------------------------------------------- validation


def test_validate_spec_accepts_good_start():
    house = box_room_house()
    dist = validate_spec(make_spec(house, 1.0, 1.0), house)
    # Straight line from (1, 1) to the chair's west face corner region: >= Euclidean gap.
    assert dist >= math.hypot(4.75 - 1.0, 1.75 - 1.0) - 0.1


@pytest.mark.parametrize(
    ("kwargs", "reason"),
    [
        (dict(x=1.0, y=1.0, goal=9), "missing"),
        (dict(x=1.0, y=1.0, goal_category="sofa"), "not a sofa"),
        (dict(x=5.0, y=2.0), "inside an obstacle"),  # on the chair
        (dict(x=1.0, y=0.15), "inside an obstacle"),  # base overlaps the south wall
        (dict(x=5.7, y=3.7), "unreachable"),  # the sealed closet
        (dict(x=9.0, y=1.0), "outside the map"),
        (dict(x=1.0, y=1.0, scene_seed=99), "scene_seed"),
        (dict(x=float("nan"), y=1.0), "not finite"),
    ],
)
def test_validate_spec_reasons(kwargs, reason):
    house = box_room_house()
    x, y = kwargs.pop("x"), kwargs.pop("y")
    goal = kwargs.pop("goal", 3)
    spec = make_spec(house, x, y, goal=goal, **kwargs)
    with pytest.raises(ValueError, match=reason):
        validate_spec(spec, house)


# ----------------------------------------------------------------------------- JSONL


def test_jsonl_round_trip_is_exact(tmp_path):
    house = box_room_house()
    specs = [
        make_spec(house, 1.0 + 0.1 * i, 1.0 / 3.0, yaw=math.pi / 7 * i, episode_id=f"val-{i}")
        for i in range(3)
    ]
    specs.append(dataclasses.replace(specs[0], num_rooms=None, instruction='a "quoted" é'))
    path = save_episodes(tmp_path / "eps" / "val.jsonl", specs)
    loaded = load_episodes(path, check=False)  # box_room_house is no generated house
    assert loaded == specs  # floats survive bit-exactly
    assert [s.start_pose.tobytes() for s in loaded] == [s.start_pose.tobytes() for s in specs]


def test_load_episodes_errors_name_the_problem(tmp_path):
    house = box_room_house()
    record = make_spec(house, 1.0, 1.0).to_dict()
    bad = dict(record, colour="red")
    path = tmp_path / "bad.jsonl"
    path.write_text(json.dumps(record) + "\n\n" + json.dumps(bad) + "\n")
    with pytest.raises(ValueError, match=r"bad.jsonl:3.*colour"):
        load_episodes(path)
    with pytest.raises(ValueError, match="does not exist"):
        load_episodes(tmp_path / "none.jsonl")
    (tmp_path / "empty.jsonl").write_text("\n")
    with pytest.raises(ValueError, match="no episodes"):
        load_episodes(tmp_path / "empty.jsonl")


OLD_KEYS = {
    "episode_id", "split", "scene_seed", "num_rooms", "clutter", "start_x", "start_y",
    "start_yaw", "goal_instance_id", "goal_category", "instruction", "geodesic_start_distance",
}  # fmt: skip
SHIPPED = (
    Path(__file__).parents[2] / "benchmarks/results/eval/episodes/test0-499_unreachable_fired.jsonl"
)


def test_a_spec_without_description_writes_exactly_the_old_record(tmp_path):
    spec = make_spec(box_room_house(), 1.0, 1.0)
    assert spec.description is None and set(spec.to_dict()) == OLD_KEYS
    path = save_episodes(tmp_path / "old.jsonl", [spec])
    old = {k: v for k, v in dataclasses.asdict(spec).items() if k not in OPTIONAL_FIELDS}
    assert path.read_text() == json.dumps(old, sort_keys=True) + "\n"
    assert EpisodeSpec.from_dict(old) == spec  # an old record loads
    assert EpisodeSpec.from_dict(dict(old, description=None)) == spec  # and asdict's form
    assert hash(spec) == hash(EpisodeSpec.from_dict(old))


@pytest.mark.skipif(not SHIPPED.is_file(), reason="shipped episodes file not in this checkout")
def test_a_shipped_episodes_file_is_rewritten_byte_for_byte(tmp_path):
    specs = load_episodes(SHIPPED)
    assert all(s.description is None for s in specs)
    again = save_episodes(tmp_path / "again.jsonl", specs)
    digest = hashlib.sha256(SHIPPED.read_bytes()).hexdigest()
    assert hashlib.sha256(again.read_bytes()).hexdigest() == digest


def test_a_description_round_trips_and_is_checked(tmp_path):
    house = box_room_house()
    fields = {"category": "chair", "color": "red", "room": None, "near": "table"}
    spec = make_spec(house, 1.0, 1.0, instruction="that red seat by the table", description=fields)
    assert spec.to_dict()["description"] == fields
    other = make_spec(house, 1.0, 1.0)
    path = save_episodes(tmp_path / "mixed.jsonl", [spec, other])
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    assert lines[0]["description"] == fields and "description" not in lines[1]
    assert load_episodes(path, check=False) == [spec, other]
    assert hash(spec) == hash(dataclasses.replace(spec, description=None))  # still hashable
    for bad, message in [
        ({"category": "chair"}, "keys"),
        ({**fields, "colour": "red"}, "keys"),
        ("chair", "got str"),
        ({**fields, "room": 3}, "str or None"),
    ]:
        with pytest.raises(ValueError, match=message):
            make_spec(house, 1.0, 1.0, description=bad)
        record = dict(spec.to_dict(), description=bad)
        path.write_text(json.dumps(record) + "\n")
        with pytest.raises(ValueError, match=rf"mixed.jsonl:1: bad episode record.*{message}"):
            load_episodes(path)


# ----------------------------------------------------------------------------- split episodes


@pytest.fixture(scope="module")
def house_module():
    pytest.importorskip("vla_gr.envs.instructions", reason="instruction generator not available")
    return pytest.importorskip("vla_gr.envs.house", reason="house generator not available")


def test_sample_episode_deterministic_and_valid(house_module):
    from vla_gr.envs.episodes import sample_episode, scene_seed_for

    a = sample_episode("val", 5)
    b = sample_episode("val", 5)
    assert a == b
    assert a.scene_seed == scene_seed_for("val", 5)
    house = house_module.generate_house(a.scene_seed, num_rooms=a.num_rooms, clutter=a.clutter)
    dist = validate_spec(a, house)
    assert MIN_START_DISTANCE <= dist <= MAX_START_DISTANCE
    assert dist == pytest.approx(a.geodesic_start_distance, abs=1e-6)
    assert house.object(a.goal_instance_id).category == a.goal_category
    assert a.instruction
    c = sample_episode("val", 6, house=house)  # same scene (4 episodes per scene), new episode
    assert c.scene_seed == a.scene_seed and c != a
    assert sample_episode("test", 5).scene_seed != a.scene_seed


def test_a_file_line_whose_instruction_does_not_describe_its_goal_is_refused(tmp_path):
    from vla_gr.envs.episodes import sample_episode
    from vla_gr.envs.house import generate_house
    from vla_gr.envs.instructions import describe_goal, goal_candidates

    spec = sample_episode("val", 5)
    house = generate_house(spec.scene_seed)
    other = next(i for i in goal_candidates(house) if i != spec.goal_instance_id)
    elsewhere = describe_goal(house, other, np.random.default_rng(0))  # another object, uniquely
    path = tmp_path / "eps.jsonl"
    cases = [
        (elsewhere, rf"eps.jsonl:2: .*describes the .* \(object {other}\), not the goal"),
        ("go to the fridge", "eps.jsonl:2: .*names no object; house .* has: "),
        (f"find the {spec.goal_category}", r"eps.jsonl:2: .*fits \d+ objects"),
    ]
    for instruction, message in cases:
        save_episodes(path, [spec, dataclasses.replace(spec, instruction=instruction)])
        with pytest.raises(EpisodeFileError, match=message) as err:
            load_episodes(path)
        assert "\n" not in str(err.value)
        # a line that declares its goal (a hand-written request) is not read
        fields = {"category": spec.goal_category, "color": None, "room": None, "near": None}
        declared = dataclasses.replace(spec, instruction=instruction, description=fields)
        save_episodes(path, [spec, declared])
        assert load_episodes(path) == [spec, declared]


def test_episodes_in_houses_of_one_to_six_rooms_cycle_through_them():
    from vla_gr.envs.episodes import sample_episode, sample_episodes_rooms_cycling

    specs = sample_episodes_rooms_cycling("val", 4000, 7)
    assert [s.num_rooms for s in specs] == [1, 2, 3, 4, 5, 6, 1]
    for spec in specs[:2]:  # each one is the split's episode of its index in such a house
        index = int(spec.episode_id.split("-")[1])
        assert sample_episode("val", index, num_rooms=spec.num_rooms) == spec
    assert [s.episode_id for s in sample_episodes_rooms_cycling("val", 4000, 7)] == [
        s.episode_id for s in specs
    ]
    with pytest.raises(ValueError, match="max_rooms"):
        sample_episodes_rooms_cycling("val", 0, 3, max_rooms=7)
