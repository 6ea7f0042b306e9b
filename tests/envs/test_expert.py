"""Geodesic expert: pure planning/control pieces on hand-built grids, then the real env."""

import math

import numpy as np
import pytest
from scipy import ndimage

from vla_gr.envs.expert import (
    ExpertConfig,
    GeodesicExpert,
    clearance_cost,
    descend_path,
    lookahead_point,
    pursuit_command,
    segment_clearance,
    wrap_angle,
)
from vla_gr.envs.geodesic import ROBOT_RADIUS
from vla_gr.envs.scene import Door, House, ObjectInstance, Room
from vla_gr.geometry import GridSpec, geodesic_distance

# ----------------------------------------------------------------------------- helpers


def two_room_house(cell: float = 0.05, doors=((1.5, 2.4),), goal_xy=(6.5, 3.2)) -> House:
    """Two 4 x 4 m rooms split by a wall at x = 4.2 with doors (y ranges); a chair as goal."""
    grid = GridSpec(0.0, 0.0, cell, int(4.4 / cell), int(8.4 / cell))
    xs, ys = grid.cell_centres()  # (H, W) each
    occ = (xs < 0.2) | (xs > 8.2) | (ys < 0.2) | (ys > 4.2)
    opening = np.zeros(grid.shape, bool)
    for y0, y1 in doors:
        opening |= (ys > y0) & (ys < y1)
    occ |= (np.abs(xs - 4.2) < 0.1) & ~opening
    goal = ObjectInstance(1, "chair", "red", 1, *goal_xy, 0.0, (0.25, 0.25), 0.8)
    ids = np.zeros(grid.shape, np.int32)
    ids[(np.abs(xs - goal.x) <= 0.25) & (np.abs(ys - goal.y) <= 0.25)] = 1
    occ |= ids > 0
    rooms = [Room(0, "kitchen", 0.2, 0.2, 4.1, 4.2), Room(1, "bedroom", 4.3, 0.2, 8.2, 4.2)]
    door_list = [Door(0, 1, 4.2, (y0 + y1) / 2, y1 - y0, "y") for y0, y1 in doors]
    return House(0, rooms, door_list, [goal], grid, occ, ids)


class KinematicWorld:
    """Unicycle integrated at ``control_hz``; a sub-step whose base would overlap an occupied
    cell is refused and counts as a collision. Exposes the ground-truth names the expert reads."""

    control_hz = 10.0
    max_linear_speed = 0.5
    max_angular_speed = 1.0
    success_distance = 1.0

    def __init__(self, house: House, start, hidden: np.ndarray | None = None) -> None:
        """``hidden`` (H, W) bool: obstacles that block motion but are missing from the map."""
        self.house, self.goal = house, house.objects[0]
        self.unwrapped = self
        footprint = house.object_ids == self.goal.instance_id
        self.goal_distance = geodesic_distance(
            1.0, footprint, house.occupancy & ~footprint, house.grid.cell_size
        )
        solid = house.occupancy if hidden is None else house.occupancy | hidden  # (H, W)
        self._clear = ndimage.distance_transform_edt(~solid) * house.grid.cell_size
        self.pose = np.array(start, float)
        self.collisions = 0

    def robot_pose_world(self) -> np.ndarray:
        return self.pose.copy()

    def clearance(self, xy) -> float:
        r, c = self.house.grid.world_to_cell(np.asarray(xy))
        return float(self._clear[r, c]) - ROBOT_RADIUS

    def step(self, action, substeps: int = 10) -> None:
        v = float(np.clip(action[0], -1, 1)) * self.max_linear_speed
        w = float(np.clip(action[1], -1, 1)) * self.max_angular_speed
        dt = 1.0 / self.control_hz / substeps
        hit = False
        for _ in range(substeps):
            x, y, yaw = self.pose
            nxt = np.array([x + v * math.cos(yaw) * dt, y + v * math.sin(yaw) * dt, yaw + w * dt])
            if self.clearance(nxt[:2]) < 0:
                hit, nxt[:2] = True, self.pose[:2]
            self.pose = nxt
        self.collisions += hit


def drive(expert: GeodesicExpert, world: KinematicWorld, max_steps: int = 400):
    expert.reset()
    poses, labels, executed = [world.pose.copy()], [], []
    for _ in range(max_steps):
        action = expert.act(None)
        labels.append(expert.last_label.copy())
        executed.append(action.copy())
        if action[2] > 0:
            break
        world.step(action)
        poses.append(world.pose.copy())
    return np.array(poses), np.array(labels), np.array(executed)


# ----------------------------------------------------------------------------- pure pieces


def test_wrap_angle():
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-3 * math.pi / 2) == pytest.approx(math.pi / 2)
    assert wrap_angle(0.3) == pytest.approx(0.3)


def test_clearance_cost_profile():
    occ = np.zeros((1, 40), bool)
    occ[0, 0] = True
    cost = clearance_cost(occ, 0.05, robot_radius=0.2, margin=0.5, weight=4.0, contact_cost=99.0)
    # cell c is 0.05 * c from the obstacle: clearance = 0.05 c - 0.2
    assert cost[0, 2] == 99.0  # overlapping the obstacle
    assert cost[0, 4] == pytest.approx(1 + 4.0)  # clearance 0
    assert cost[0, 9] == pytest.approx(1 + 4.0 * (1 - 0.25 / 0.5) ** 2)
    assert cost[0, 14] == pytest.approx(1.0) and cost[0, 30] == 1.0
    assert np.all(np.diff(cost[0, 4:]) <= 0)  # never cheaper closer to walls
    with pytest.raises(ValueError, match="margin"):
        clearance_cost(occ, 0.05, margin=0.0)


def test_descend_path_empty_room_is_straight():
    grid = GridSpec(0.0, 0.0, 0.1, 50, 50)
    sources = np.zeros(grid.shape, bool)
    sources[40, 40] = True  # centre (4.05, 4.05)
    field = geodesic_distance(1.0, sources, None, 0.1)
    path = descend_path(field, grid, np.array([0.55, 0.55]), max_length=100.0)  # (N, 2)
    assert np.allclose(path[-1], [4.05, 4.05])
    assert np.all(np.abs(path[:, 0] - path[:, 1]) < 1e-9)  # along the diagonal
    values = [field[tuple(grid.world_to_cell(p))] for p in path]
    assert np.all(np.diff(values) < 0)  # strictly downhill
    short = descend_path(field, grid, np.array([0.55, 0.55]), max_length=1.0)
    assert 1.0 <= np.linalg.norm(np.diff(short, axis=0), axis=1).sum() < 1.0 + 0.15


def test_descend_path_goes_through_the_door():
    house = two_room_house()
    footprint = house.object_ids == 1
    field = geodesic_distance(1.0, footprint, house.occupancy & ~footprint, 0.05)
    path = descend_path(field, house.grid, np.array([1.0, 3.5]), max_length=100.0)
    crossing = path[np.argmin(np.abs(path[:, 0] - 4.2))]
    assert 1.5 < crossing[1] < 2.4  # the only way through the wall
    assert field[tuple(house.grid.world_to_cell(path[-1]))] == 0.0


def test_lookahead_respects_line_of_sight():
    grid = GridSpec(0.0, 0.0, 0.1, 30, 30)
    occ = np.zeros(grid.shape, bool)
    occ[10:, 12] = True  # a wall at x = 1.25 from y = 1.0 up
    clearance = ndimage.distance_transform_edt(~occ) * 0.1 - 0.2  # (H, W)
    # an L-shaped path: right along y = 0.55, then up along x = 2.05
    path = [[0.55 + 0.1 * i, 0.55] for i in range(16)] + [
        [2.05, 0.55 + 0.1 * i] for i in range(1, 20)
    ]
    path = np.array(path)  # (N, 2)
    far = lookahead_point(path, 2.5)
    assert np.allclose(far, path[25])
    seen = lookahead_point(path, 2.5, clearance, grid, min_clearance=0.05)
    assert segment_clearance(clearance, grid, path[0], seen) >= 0.05
    assert np.linalg.norm(seen - path[0]) < np.linalg.norm(far - path[0])
    assert segment_clearance(clearance, grid, path[0], far) < 0.05
    # the segment to the next path point is always allowed, even from a tight spot
    assert np.allclose(lookahead_point(path[:3], 1.0, np.full(grid.shape, -1.0), grid), path[2])
    assert segment_clearance(clearance, grid, path[0], np.array([-1.0, 0.5])) == -math.inf


def test_tight_start_can_still_look_ahead():
    grid = GridSpec(0.0, 0.0, 0.1, 20, 40)
    occ = np.zeros(grid.shape, bool)
    occ[0, :] = True  # a wall along y = 0.05
    clearance = ndimage.distance_transform_edt(~occ) * 0.1 - 0.2  # (H, W)
    # robot 0.25 m from the wall (clearance 0.0 < min), path runs parallel, then away
    path = np.array([[0.55 + 0.1 * i, 0.25] for i in range(10)])  # (N, 2)
    target = lookahead_point(path, 0.6, clearance, grid, min_clearance=0.1)
    assert np.allclose(target, path[6])  # parallel: no closer than now, so full lookahead


def test_pursuit_command_signs_and_limits():
    pose = np.array([0.0, 0.0, 0.0])
    v, w = pursuit_command(pose, np.array([1.0, 0.0]), 0.5, 1.0)
    assert v == pytest.approx(0.5) and w == pytest.approx(0.0)
    v, w = pursuit_command(pose, np.array([1.0, 0.3]), 0.5, 1.0)
    assert 0 < v < 0.5 and w > 0  # target on the left: turn left while driving
    # the commanded arc passes through the target: curvature w / v = 2 sin(alpha) / L
    alpha, dist = math.atan2(0.3, 1.0), math.hypot(1.0, 0.3)
    assert w / v == pytest.approx(2 * math.sin(alpha) / dist)
    v, w = pursuit_command(pose, np.array([-1.0, -0.1]), 0.5, 1.0)
    assert v == 0.0 and w == pytest.approx(-1.0)  # behind, to the right: turn in place
    v, w = pursuit_command(pose, np.array([0.05, 0.05]), 0.5, 1.0)
    assert abs(w) <= 1.0 and v * abs(2 * math.sin(math.pi / 4) / math.hypot(0.05, 0.05)) <= 1.0


def test_expert_config_validation():
    with pytest.raises(ValueError, match="stop_distance"):
        ExpertConfig(stop_distance=0.0)
    world = KinematicWorld(two_room_house(), (1.0, 0.8, 0.0))
    with pytest.raises(ValueError, match="noise_prob"):
        GeodesicExpert(world, noise_prob=1.5)
    with pytest.raises(ValueError, match="noise_std"):
        GeodesicExpert(world, noise_std=-1.0)


# ----------------------------------------------------------------- closed loop (kinematic)


@pytest.mark.parametrize("start", [(1.0, 0.8, 0.0), (0.8, 3.6, -2.5), (3.5, 1.0, math.pi)])
def test_expert_reaches_and_faces_goal_in_kinematic_world(start):
    world = KinematicWorld(two_room_house(), start)
    expert = GeodesicExpert(world)
    poses, labels, executed = drive(expert, world)
    assert executed[-1][2] > 0, "expert never called STOP"
    assert np.array_equal(labels, executed)  # no noise: executes its own labels
    d_final = expert.distance_to_goal(poses[-1, :2])
    assert d_final <= expert.config.stop_distance + 1e-9
    goal = world.goal
    heading = math.atan2(goal.y - poses[-1, 1], goal.x - poses[-1, 0])
    assert abs(wrap_angle(heading - poses[-1, 2])) <= expert.config.face_tolerance
    assert world.collisions == 0
    travelled = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1).sum()
    l_star = expert.distance_to_goal(np.array(start[:2]))
    assert travelled <= l_star  # stops ~0.75 m early and never detours much
    assert np.all(np.abs(executed[:, :2]) <= 1.0)
    # smooth: the angular command never flips sign at full rate between steps
    assert np.max(np.abs(np.diff(executed[:, 1]))) < 1.5


def test_noisy_expert_recovers_and_labels_differ():
    world = KinematicWorld(two_room_house(), (1.0, 0.8, 0.0))
    expert = GeodesicExpert(world, noise_std=0.3, noise_prob=0.1, seed=3)
    poses, labels, executed = drive(expert, world, max_steps=600)
    assert executed[-1][2] > 0 and labels[-1][2] > 0
    assert expert.distance_to_goal(poses[-1, :2]) <= expert.config.stop_distance + 1e-9
    differ = np.any(np.abs(labels[:-1, :2] - executed[:-1, :2]) > 1e-6, axis=1)
    assert differ.mean() > 0.5
    assert np.all(executed[:-1, 2] < 0)  # noise never triggers STOP
    # same seed, same world -> identical noisy rollout
    world2 = KinematicWorld(two_room_house(), (1.0, 0.8, 0.0))
    _, _, executed2 = drive(
        GeodesicExpert(world2, noise_std=0.3, noise_prob=0.1, seed=3), world2, 600
    )
    assert np.array_equal(executed, executed2)


# ----------------------------------------------------------------- the real env

VAL_EPISODES = 5


@pytest.fixture(scope="module")
def val_env():
    gym = pytest.importorskip("gymnasium")
    import vla_gr.envs  # noqa: F401  (registers VLAGR/ObjectNav-v0)

    env = gym.make("VLAGR/ObjectNav-v0", split="val", image_size=64)
    yield env
    env.close()


def run_real_episode(env, expert, index: int):
    obs, info = env.reset(options={"episode": index})
    expert.reset()
    labels, executed = [], []
    terminated = truncated = False
    while not (terminated or truncated):
        action = expert.act(obs)
        labels.append(expert.last_label.copy())
        executed.append(action.copy())
        obs, _, terminated, truncated, info = env.step(action)
    return info, np.array(labels), np.array(executed), terminated


def test_expert_solves_val_episodes(val_env):
    expert = GeodesicExpert(val_env)
    infos = []
    for k in range(VAL_EPISODES):
        info, labels, executed, terminated = run_real_episode(val_env, expert, k)
        assert terminated, f"episode {k}: ran out of steps"
        assert np.array_equal(labels, executed)
        infos.append(info)
    assert all(i["success"] == 1.0 for i in infos), [i["distance_to_goal"] for i in infos]
    assert np.mean([i["spl"] for i in infos]) > 0.85
    assert sum(i["collisions"] for i in infos) <= 1
    for i in infos:  # stopped inside the success radius with the intended margin
        assert i["distance_to_goal"] <= expert.config.stop_distance + 0.05


def test_noisy_expert_solves_val_episodes(val_env):
    expert = GeodesicExpert(val_env, noise_std=0.2, noise_prob=0.05, seed=0)
    for k in range(2):
        info, labels, executed, terminated = run_real_episode(val_env, expert, k)
        assert terminated and info["success"] == 1.0, f"episode {k}: {info}"
        differ = np.any(np.abs(labels[:-1, :2] - executed[:-1, :2]) > 1e-6, axis=1)
        assert differ.mean() > 0.5
        assert labels[-1][2] > 0 and executed[-1][2] > 0


def test_blocked_door_replans_through_the_other_door():
    house = two_room_house(doors=((0.8, 1.7), (3.0, 3.9)), goal_xy=(6.5, 1.0))
    xs, ys = house.grid.cell_centres()  # (H, W) each
    glass = (np.abs(xs - 4.2) < 0.1) & (ys > 0.8) & (ys < 1.7)  # the near door is shut
    world = KinematicWorld(house, (1.0, 1.2, 0.0), hidden=glass)
    expert = GeodesicExpert(world)
    poses, _, executed = drive(expert, world, max_steps=800)
    assert executed[-1][2] > 0 and not expert.gave_up
    assert expert.distance_to_goal(poses[-1, :2]) <= expert.config.stop_distance + 1e-9
    assert np.any((np.abs(poses[:, 0] - 4.2) < 0.3) & (poses[:, 1] > 3.0))  # used door 2
    assert 1 <= world.collisions <= 10


def test_unreachable_goal_gives_up_with_stop():
    house = two_room_house()
    xs, ys = house.grid.cell_centres()  # (H, W) each
    glass = (np.abs(xs - 4.2) < 0.1) & (ys > 1.4) & (ys < 2.5)  # the only door is shut
    world = KinematicWorld(house, (1.0, 0.8, 0.0), hidden=glass)
    expert = GeodesicExpert(world)
    poses, _, executed = drive(expert, world, max_steps=1000)
    assert executed[-1][2] > 0 and expert.gave_up
    assert len(executed) < 300 and world.collisions <= 60  # gives up, does not grind
    assert expert.distance_to_goal(poses[-1, :2]) > 1.0
    # the next episode plans again from the house's own map
    world.pose = np.array([1.0, 0.8, 0.0])
    expert.reset()
    assert not expert.gave_up and expert._replans == 0
