"""Local teacher: STOP only inside the success distance, collision-free waypoint following,
guarded open-loop commands, config validation; all in the real env."""

import math

import gymnasium as gym
import numpy as np
import pytest

import vla_gr.envs  # noqa: F401  (registers the id)
from vla_gr.envs import ENV_ID
from vla_gr.envs import robot as rb
from vla_gr.envs.geodesic import ROBOT_RADIUS
from vla_gr.envs.local_teacher import LocalTeacher, LocalTeacherConfig
from vla_gr.geometry import geodesic_distance

from .test_episodes import box_room_house
from .test_nav_env import EAST_WALL, room_spec

ZERO = np.array([0.0, 0.0, -1.0], np.float32)


@pytest.fixture(scope="module")
def val_env():
    env = gym.make(ENV_ID, split="val", image_size=16)
    yield env
    env.close()


@pytest.fixture(scope="module")
def room():
    return box_room_house()


@pytest.fixture(scope="module")
def room_env():
    env = gym.make(ENV_ID, image_size=16)
    yield env
    env.close()


def place(env, world_pose):
    """Put the robot at ``world_pose`` (3,) and take a still step: (obs, info) there."""
    s = env.unwrapped._scene
    rb.set_robot_pose(s.model, s.data, s.robot, np.asarray(world_pose, np.float64))
    obs, _, _, _, info = env.step(ZERO)
    return obs, info


def to_odometry(env, xy) -> np.ndarray:
    """World point (2,) -> odometry frame (1, 2), as S2 would hand it over."""
    u = env.unwrapped
    return rb.relative_pose(np.array([xy[0], xy[1], 0.0]), u.start_pose_world)[None, :2]


def drive(env, teacher, obs, waypoints, max_steps: int):
    """Step the env with the teacher's actions until it stands still; (obs, collisions, n)."""
    collisions = 0
    for n in range(max_steps):
        action = teacher.act(obs["pose"], waypoints)
        assert action.dtype == np.float32 and action.shape == (3,) and action[2] == -1.0
        if np.all(action[:2] == 0.0):
            return obs, collisions, n
        obs, _, term, trunc, info = env.step(action)
        assert not (term or trunc)
        collisions += int(info["collided"])
    return obs, collisions, max_steps


# ----------------------------------------------------------------------------- STOP


def test_stop_only_inside_success_distance_minus_margin(val_env):
    # start yaw 0.74 rad: odometry and world frames differ
    _, info = val_env.reset(options={"episode": 0})
    teacher = LocalTeacher(val_env)
    teacher.reset()
    u = val_env.unwrapped
    limit = u.success_distance - teacher.config.stop_margin
    field, grid = u.goal_distance, u.house.grid  # (H, W)
    cells = np.argwhere(u.traversable & np.isfinite(field))  # (N, 2)
    d = field[cells[:, 0], cells[:, 1]]  # (N,)
    rng = np.random.default_rng(0)
    bands = {"inside": (0.3, limit - 0.03), "margin": (limit + 0.03, 0.98), "far": (1.5, 4.0)}
    stops = {}
    for name, (lo, hi) in bands.items():
        pick = cells[(d > lo) & (d < hi)]
        assert len(pick) >= 3, name
        for r, c in pick[rng.choice(len(pick), 3, replace=False)]:
            x, y = grid.cell_to_world(np.array([r, c]))
            obs, info = place(val_env, (x, y, rng.uniform(-math.pi, math.pi)))
            measured = teacher.goal_distance(obs["pose"])
            assert measured == pytest.approx(info["distance_to_goal"], abs=1e-3)
            action = teacher.act(obs["pose"], np.zeros((0, 2)), stop_requested=True)
            stops.setdefault(name, []).append(action.tolist())
            # Not requested: never STOP, whatever S2 hands over, even at the goal.
            ahead = obs["pose"][None, :2] + 1.0
            for kw in ({}, {"command": (0.0, 0.5)}):
                assert teacher.act(obs["pose"], np.zeros((0, 2)), **kw)[2] == -1.0
            assert teacher.act(obs["pose"], ahead)[2] == -1.0
    assert all(a == [0.0, 0.0, 1.0] for a in stops["inside"]), stops
    assert all(a == [0.0, 0.0, -1.0] for a in stops["margin"] + stops["far"]), stops
    # The teacher's STOP is a successful STOP for the env.
    inside = cells[(d > 0.3) & (d < limit - 0.03)][0]
    obs, _ = place(val_env, (*grid.cell_to_world(inside), 0.0))
    action = teacher.act(obs["pose"], np.zeros((0, 2)), stop_requested=True)
    _, reward, terminated, _, info = val_env.step(action)
    assert terminated and info["success"] == 1.0 and reward == 1.0


# ----------------------------------------------------------------------------- driving


def test_reaches_a_waypoint_around_obstacles_without_collision(val_env):
    obs, _ = val_env.reset(options={"episode": 4})  # start yaw -0.93 rad
    teacher = LocalTeacher(val_env)
    teacher.reset()
    u = val_env.unwrapped
    grid = u.house.grid
    start = u.robot_pose_world()  # (3,)
    source = np.zeros(grid.shape, bool)  # (H, W)
    source[tuple(grid.world_to_cell(start[:2]))] = True
    geo = geodesic_distance(1.0, source, ~u.traversable, grid.cell_size)  # (H, W)
    cells = np.argwhere((geo > 2.5) & (geo < 4.0))  # (N, 2) a few metres away on free space
    xy = grid.cell_to_world(cells)  # (N, 2)
    detour = geo[cells[:, 0], cells[:, 1]] / np.linalg.norm(xy - start[:2], axis=1)  # (N,)
    k = int(np.argmax(detour))  # the target the straight line cannot reach
    assert detour[k] > 1.15
    target = xy[k]
    obs, collisions, steps = drive(val_env, teacher, obs, to_odometry(val_env, target), 150)
    assert steps < 150 and collisions == 0
    final = u.robot_pose_world()
    assert math.dist(final[:2], target) <= teacher.config.arrive_distance
    assert len(teacher.replan_seconds) == 1  # a fixed target is planned once
    # A target that moves less than a cell keeps the plan; more than a cell re-plans.
    teacher.act(obs["pose"], to_odometry(val_env, target + 0.3))
    teacher.act(obs["pose"], to_odometry(val_env, target + 0.32))
    assert len(teacher.replan_seconds) == 2
    assert max(teacher.replan_seconds) < 0.5


def test_unreachable_waypoint_is_approached_as_near_as_the_robot_fits(room_env, room):
    obs, _ = room_env.reset(options={"episode": room_spec(1.0, 1.0, 0.5), "house": room})
    teacher = LocalTeacher(room_env)
    teacher.reset()
    target = np.array([5.7, 3.7])  # inside the walled-off closet
    obs, collisions, steps = drive(room_env, teacher, obs, to_odometry(room_env, target), 200)
    assert steps < 200 and collisions == 0
    final = room_env.unwrapped.robot_pose_world()
    # The closest place the robot fits is against the closet's west wall (x = 5.2), level
    # with the target: about 5.2 - 0.22 (robot radius and slack), 3.7.
    assert final[0] < 5.2 - ROBOT_RADIUS
    assert math.dist(final[:2], (5.2 - 0.22, 3.7)) <= teacher.config.arrive_distance + 0.05
    assert teacher.act(obs["pose"], np.zeros((0, 2))).tolist() == ZERO.tolist()


# ----------------------------------------------------------------------------- commands


def test_command_passes_when_free_and_loses_its_forward_part_at_a_wall(room_env, room):
    room_env.reset(options={"episode": room_spec(3.0, 1.0, 0.0), "house": room})
    teacher = LocalTeacher(room_env)
    teacher.reset()
    none = np.zeros((0, 2))
    obs, _ = place(room_env, (3.0, 1.0, 0.0))  # open floor ahead
    assert teacher.act(obs["pose"], none, command=(0.7, -0.3)).tolist() == pytest.approx(
        [0.7, -0.3, -1.0]
    )
    assert teacher.act(obs["pose"], none, command=(1.7, -2.0)).tolist() == [1.0, -1.0, -1.0]
    # Touching the east wall, facing it: forward is refused, turning and backing off are not.
    x = EAST_WALL - 0.19
    obs, _ = place(room_env, (x, 1.0, 0.0))
    guarded = teacher.act(obs["pose"], none, command=(0.8, 0.3))
    assert guarded.tolist() == pytest.approx([0.0, 0.3, -1.0])
    assert teacher.act(obs["pose"], none, command=(-0.8, 0.0))[0] == pytest.approx(-0.8)
    _, _, _, _, info = room_env.step(guarded)
    assert not info["collided"]
    place(room_env, (x, 1.0, 0.0))
    _, _, _, _, info = room_env.step(np.array([0.8, 0.0, -1.0], np.float32))
    assert info["collided"]  # unguarded, it would have hit the wall
    # Backing into the wall is refused as well; facing away, the command passes.
    obs, _ = place(room_env, (x, 1.0, math.pi))
    assert teacher.act(obs["pose"], none, command=(-0.8, 0.0))[0] == 0.0
    assert teacher.act(obs["pose"], none, command=(0.8, 0.3)).tolist() == pytest.approx(
        [0.8, 0.3, -1.0]
    )


# ----------------------------------------------------------------------------- config


@pytest.mark.parametrize(
    "field, value",
    [
        ("stop_margin", -0.1),
        ("arrive_distance", 0.0),
        ("lookahead", -1.0),
        ("clearance_weight", math.nan),
        ("command_horizon_steps", 0),
        ("command_horizon_steps", 1.5),
    ],
)
def test_config_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        LocalTeacherConfig(**{field: value})


def test_stop_margin_must_leave_a_success_region(room_env, room):
    room_env.reset(options={"episode": room_spec(3.0, 1.0, 0.0), "house": room})
    teacher = LocalTeacher(room_env, LocalTeacherConfig(stop_margin=1.0))
    with pytest.raises(ValueError, match="stop_margin"):
        teacher.reset()
    with pytest.raises(RuntimeError, match="reset"):
        teacher.act(np.zeros(3), np.zeros((0, 2)))
