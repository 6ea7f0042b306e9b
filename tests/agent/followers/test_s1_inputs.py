"""What the learned S1 reads: the plan vector (hand-computed frames and slots) and the pooled
RGB-D."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vla_gr.agent.followers.s1_inputs import PlanMemory, plan_vector_size, pool_rgbd
from vla_gr.agent.navigator.navigator import MODES, NavPlan

POINTS = (0.25, 0.5, 1.0, 2.0)
N = 2 * len(POINTS)  # path slots
HAS_PATH, PATH_END = N, N + 1
CMD_V, CMD_W, HAS_CMD, STOP, CONF, GOAL_D, GOAL_KNOWN, SPEED = range(N + 2, N + 10)
MODE0 = N + 10
AGE = -1


def _plan(waypoints=((1.0, 0.0), (1.0, 1.0)), **kw) -> NavPlan:
    args = dict(mode="approach", goal_confidence=0.7, stop=False)
    args.update(kw)
    return NavPlan(np.asarray(waypoints, np.float64).reshape(-1, 2), **args)


def test_size_is_the_documented_layout():
    assert plan_vector_size(POINTS) == 8 + 2 + 3 + 1 + 3 + 1 + 6 + 1 == 25
    assert plan_vector_size([1.0]) == 2 + 2 + 3 + 1 + 3 + 1 + len(MODES) + 1
    memory = PlanMemory(POINTS)
    assert memory.size == 25
    memory.set_plan(_plan(), np.zeros(3), 0)
    assert memory.vector(np.zeros(3), 0).shape == (25,)
    assert memory.vector(np.zeros(3), 0).dtype == np.float32


def test_path_points_follow_the_robot_by_odometry():
    # Plan made at (1, 2) facing +y: forward 1 m, then 1 m to the left.
    # World: (1, 3) and (0, 3).
    memory = PlanMemory(POINTS)
    memory.set_plan(_plan(), np.array([1.0, 2.0, math.pi / 2]), step=4)
    np.testing.assert_allclose(memory.waypoints_world, [[1.0, 3.0], [0.0, 3.0]], atol=1e-12)

    # At the plan's own pose the path is the plan's (robot at the origin):
    # (0,0) -> (1,0) -> (1,1); arc 0.25, 0.5, 1.0, 2.0 (clipped to 2.0 = the end).
    v = memory.vector(np.array([1.0, 2.0, math.pi / 2]), 4)
    expected = np.array([[0.25, 0.0], [0.5, 0.0], [1.0, 0.0], [1.0, 1.0]]) / 2.0
    np.testing.assert_allclose(v[:N].reshape(-1, 2), expected, atol=1e-6)
    assert v[HAS_PATH] == 1.0
    assert v[PATH_END] == pytest.approx(math.sqrt(2.0) / 5.0)

    # The robot drove 0.5 m along +y and turned to face -x: in its frame (forward, left) the
    # waypoints (1, 3) and (0, 3) are (0, -0.5) (to its right) and (1, -0.5).
    # Path (0,0) -> (0,-0.5) -> (1,-0.5): arc 0.25 (0,-0.25), 0.5 (0,-0.5), 1.0 (0.5,-0.5),
    # 2.0 -> the end (1,-0.5).
    v = memory.vector(np.array([1.0, 2.5, math.pi]), 7)
    expected = np.array([[0.0, -0.25], [0.0, -0.5], [0.5, -0.5], [1.0, -0.5]]) / 2.0
    np.testing.assert_allclose(v[:N].reshape(-1, 2), expected, atol=1e-6)
    assert v[PATH_END] == pytest.approx(math.hypot(1.0, 0.5) / 5.0)
    assert v[AGE] == pytest.approx(0.3)  # 3 steps since the plan
    assert memory.vector(np.array([1.0, 2.5, math.pi]), 40)[AGE] == 1.0  # clipped at 10

    # Far from the path's end: the distance slot saturates at 5 m.
    far = memory.vector(np.array([20.0, 3.0, 0.0]), 5)
    assert far[PATH_END] == 1.0


def test_command_stop_confidence_speed_and_mode_slots():
    memory = PlanMemory(POINTS)
    plan = _plan(
        waypoints=np.zeros((0, 2)), mode="verify", goal_confidence=0.6, stop=True,
        command=(0.25, -0.5), goal_distance=2.5, max_speed=0.4,
    )  # fmt: skip
    memory.set_plan(plan, np.array([3.0, -1.0, 0.3]), step=2)
    v = memory.vector(np.array([3.5, -1.0, 0.1]), 2)
    assert memory.waypoints_world is None and memory.plan is plan
    assert not v[: HAS_PATH + 2].any()  # no path: no points, no 'has path', no distance
    assert (v[CMD_V], v[CMD_W], v[HAS_CMD]) == (0.25, -0.5, 1.0)
    assert v[STOP] == 1.0
    assert v[CONF] == pytest.approx(0.6)
    assert v[GOAL_D] == pytest.approx(0.5) and v[GOAL_KNOWN] == 1.0
    assert v[SPEED] == pytest.approx(0.4)
    modes = v[MODE0 : MODE0 + len(MODES)]
    assert modes.sum() == 1.0 and modes[MODES.index("verify")] == 1.0
    assert v[AGE] == 0.0

    for mode in MODES:  # every mode has its own slot
        memory.set_plan(_plan(mode=mode), np.zeros(3), 0)
        one_hot = memory.vector(np.zeros(3), 0)[MODE0 : MODE0 + len(MODES)]
        assert one_hot.tolist() == [float(m == mode) for m in MODES]

    # No command, no stop, an unknown goal distance; a far goal saturates at 5 m.
    memory.set_plan(_plan(goal_distance=math.inf), np.zeros(3), 0)
    v = memory.vector(np.zeros(3), 0)
    assert (v[CMD_V], v[CMD_W], v[HAS_CMD], v[STOP]) == (0.0, 0.0, 0.0, 0.0)
    assert v[GOAL_D] == 0.0 and v[GOAL_KNOWN] == 0.0
    memory.set_plan(_plan(goal_distance=12.0), np.zeros(3), 0)
    v = memory.vector(np.zeros(3), 0)
    assert v[GOAL_D] == 1.0 and v[GOAL_KNOWN] == 1.0


def test_no_plan_is_zeros_but_the_age_slot():
    memory = PlanMemory(POINTS)
    v = memory.vector(np.array([1.0, 2.0, 0.5]), 3)
    assert not v[:AGE].any() and v[AGE] == pytest.approx(0.3)
    memory.set_plan(_plan(command=(1.0, 0.0)), np.zeros(3), 0)
    memory.reset()
    v = memory.vector(np.array([1.0, 2.0, 0.5]), 0)
    assert memory.plan is None and not v.any()


def _hand_pool(img: np.ndarray, size: int) -> np.ndarray:
    H, W = img.shape[:2]
    fh, fw = H // size, W // size
    out = np.zeros((size, size) + img.shape[2:])
    for r in range(size):
        for c in range(size):
            total = 0.0
            for i in range(fh):
                for j in range(fw):
                    total = total + img[r * fh + i, c * fw + j].astype(np.float64)
            out[r, c] = total / (fh * fw)
    return out


def test_pool_rgbd_is_the_block_average():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (6, 4, 3)).astype(np.uint8)
    depth = rng.uniform(0.5, 9.0, (6, 4, 1)).astype(np.float32)
    small_rgb, small_depth = pool_rgbd(rgb, depth, 2)
    assert small_rgb.shape == (3, 2, 2) and small_rgb.dtype == np.uint8
    assert small_depth.shape == (1, 2, 2) and small_depth.dtype == np.float32
    np.testing.assert_array_equal(small_rgb, np.rint(_hand_pool(rgb, 2)).transpose(2, 0, 1))
    np.testing.assert_allclose(small_depth[0], _hand_pool(depth[..., 0], 2), rtol=1e-6)
    # (H, W) depth is the same as (H, W, 1); a NaN / inf pixel counts as 0 m
    np.testing.assert_array_equal(pool_rgbd(rgb, depth[..., 0], 2)[1], small_depth)
    holes = depth.copy()
    holes[0, 0, 0], holes[5, 3, 0] = np.nan, np.inf
    pooled = pool_rgbd(rgb, holes, 2)[1][0]
    filled = np.where(np.isfinite(holes[..., 0]), holes[..., 0], 0.0)
    np.testing.assert_allclose(pooled, _hand_pool(filled, 2), rtol=1e-6)
    # size 1 is the whole-image mean
    np.testing.assert_allclose(pool_rgbd(rgb, depth, 1)[1].item(), depth.mean(), rtol=1e-6)


@pytest.mark.parametrize(
    ("rgb_shape", "depth_shape", "size"),
    [((6, 6, 3), (6, 6, 1), 4), ((8, 6, 3), (8, 6), 4), ((8, 8, 3), (4, 4, 1), 4)],
)
def test_pool_rgbd_rejects_sizes_that_do_not_divide(rgb_shape, depth_shape, size):
    with pytest.raises(ValueError, match=f"divisible by {size}"):
        pool_rgbd(np.zeros(rgb_shape, np.uint8), np.zeros(depth_shape, np.float32), size)
