"""Metrics on hand-built trajectories with hand-computed answers."""

import math

import numpy as np
import pytest

from vla_gr.envs.metrics import (
    SPL,
    Collisions,
    EpisodeMeasures,
    PathLength,
    SoftSPL,
    Success,
    aggregate,
    format_table,
    path_length_of,
    soft_spl_value,
    spl_value,
)


def run_episode(steps, start=(0.0, 0.0), l_star=4.0, success_distance=1.0):
    """steps: list of (xy, distance_to_goal, collided, called_stop)."""
    m = EpisodeMeasures(success_distance=success_distance)
    m.reset(start, l_star)
    for xy, d, col, stop in steps:
        m.update(xy, d, col, stop)
    return m.as_info()


def test_straight_success_is_spl_one():
    # 4 m straight to the goal region boundary, 1 m steps, stop at 0.5 m: l = 4 = l*.
    steps = [((1.0, 0), 3.5, False, False), ((2.0, 0), 2.5, False, False)]
    steps += [((3.0, 0), 1.5, False, False), ((4.0, 0), 0.5, False, True)]
    info = run_episode(steps)
    assert info["success"] == 1.0
    assert info["spl"] == pytest.approx(1.0)
    assert info["path_length"] == pytest.approx(4.0)
    assert info["steps"] == 4
    assert info["collisions"] == 0 and info["collision_rate"] == 0.0
    # soft-SPL: progress 1 - 0.5/4 = 0.875, efficiency 1
    assert info["soft_spl"] == pytest.approx(0.875)
    assert info["geodesic_start_distance"] == 4.0


def test_longer_path_scales_spl():
    # A detour: 3-4-5 triangle legs (3 + 4) then 1 m more = 8 m travelled, l* = 4.
    steps = [((3.0, 0), 3.0, False, False), ((3.0, 4.0), 2.0, True, False)]
    steps += [((3.0, 5.0), 0.8, False, True)]
    info = run_episode(steps, l_star=4.0)
    assert info["path_length"] == pytest.approx(8.0)
    assert info["success"] == 1.0
    assert info["spl"] == pytest.approx(4.0 / 8.0)
    assert info["soft_spl"] == pytest.approx((1 - 0.8 / 4.0) * 0.5)
    assert info["collisions"] == 1
    assert info["collision_rate"] == pytest.approx(1 / 3)


def test_stop_too_far_fails_but_soft_spl_credits_progress():
    steps = [((1.0, 0), 3.0, False, False), ((2.0, 0), 1.2, False, True)]
    info = run_episode(steps, l_star=4.0)
    assert info["success"] == 0.0 and info["spl"] == 0.0
    # progress 1 - 1.2/4 = 0.7; l = 2 < l* = 4 so efficiency 1
    assert info["soft_spl"] == pytest.approx(0.7)


def test_no_stop_is_failure_even_at_goal():
    steps = [((1.0, 0), 0.2, False, False), ((1.0, 0.5), 0.0, False, False)]
    info = run_episode(steps, l_star=1.0)
    assert info["success"] == 0.0 and info["spl"] == 0.0
    assert info["distance_to_goal"] == 0.0
    # soft-SPL: full progress, l = 1.5 > l* = 1 -> 1/1.5
    assert info["soft_spl"] == pytest.approx(1 / 1.5)


def test_success_boundary_inclusive_and_custom_threshold():
    assert run_episode([((0.1, 0), 1.0, False, True)], l_star=1.1)["success"] == 1.0
    assert (
        run_episode([((0.1, 0), 1.0, False, True)], l_star=1.1, success_distance=0.5)["success"]
        == 0.0
    )


def test_success_frozen_after_stop():
    s = Success(1.0)
    s.reset()
    s.update(True, 0.5)
    s.update(True, 5.0)  # anything after STOP is ignored
    assert s.value == 1.0 and s.stopped


def test_moving_away_gives_zero_soft_spl():
    info = run_episode([((-1.0, 0), 5.0, False, True)], l_star=4.0)
    assert info["soft_spl"] == 0.0 and info["success"] == 0.0


def test_unreachable_distance_is_no_progress():
    assert soft_spl_value(math.inf, 3.0, 1.0) == 0.0


def test_collision_rate_counts_steps():
    c = Collisions()
    c.reset()
    for flag in [True, False, False, True, True]:
        c.update(flag)
    assert c.value == 3 and c.steps == 5 and c.rate == pytest.approx(0.6)
    c.reset()
    assert c.rate == 0.0


def test_path_length_measure_matches_pure_function(rng):
    xy = np.cumsum(rng.normal(size=(50, 2)), axis=0)  # (T, 2)
    p = PathLength()
    p.reset(xy[0])
    for point in xy[1:]:
        p.update(point)
    assert p.value == pytest.approx(path_length_of(xy))
    assert path_length_of(np.array([[0, 0], [3, 4], [3, 0]])) == pytest.approx(9.0)
    assert path_length_of(np.zeros((1, 2))) == 0.0


def test_spl_and_soft_spl_classes():
    spl, soft = SPL(), SoftSPL()
    spl.reset(2.0)
    soft.reset(2.0)
    assert soft.value == 0.0
    spl.update(1.0, 3.0)
    soft.update(0.5, 3.0)
    assert spl.value == pytest.approx(2 / 3)
    assert soft.value == pytest.approx(0.75 * 2 / 3)


def test_pure_functions_edge_cases():
    assert spl_value(True, 0.0, 0.0) == 1.0  # started on the goal and stopped
    assert spl_value(False, 5.0, 1.0) == 0.0
    assert spl_value(True, 5.0, 2.0) == 1.0  # l < l* (cut through the goal region) caps at 1
    with pytest.raises(ValueError, match="shortest"):
        spl_value(True, -1.0, 1.0)
    with pytest.raises(ValueError, match="final_distance"):
        soft_spl_value(float("nan"), 1.0, 1.0)
    with pytest.raises(ValueError, match="success_distance"):
        Success(0.0)
    with pytest.raises(ValueError, match="xy"):
        path_length_of(np.zeros((3, 3)))


def test_bad_inputs_raise():
    m = EpisodeMeasures()
    with pytest.raises(RuntimeError):
        m.update((0, 0), 1.0, False, False)
    with pytest.raises(ValueError, match="geodesic_start_distance"):
        m.reset((0, 0), -2.0)
    m.reset((0, 0), 2.0)
    with pytest.raises(ValueError, match="xy"):
        m.update((float("nan"), 0), 1.0, False, False)


def test_reset_clears_state():
    m = EpisodeMeasures()
    m.reset((0, 0), 3.0)
    m.update((1, 0), 0.5, True, True)
    m.reset((5, 5), 2.0)
    info = m.as_info()
    assert info["steps"] == 0 and info["path_length"] == 0.0 and info["success"] == 0.0
    assert info["collisions"] == 0 and info["distance_to_goal"] == 2.0


def test_aggregate_means():
    a = {"success": 1.0, "spl": 0.8, "soft_spl": 0.9, "collision_rate": 0.0}
    a |= {"path_length": 4.0, "distance_to_goal": 0.5}
    b = {"success": 0.0, "spl": 0.0, "soft_spl": 0.5, "collisions": 2, "steps": 8}
    b |= {"path_length": 6.0, "distance_to_goal": 2.5}
    agg = aggregate([a, b])
    assert agg["episodes"] == 2
    assert agg["success"] == pytest.approx(0.5)
    assert agg["spl"] == pytest.approx(0.4)
    assert agg["soft_spl"] == pytest.approx(0.7)
    assert agg["collision_rate"] == pytest.approx(0.125)  # mean of 0 and 2/8
    assert agg["path_length"] == pytest.approx(5.0)
    assert agg["distance_to_goal"] == pytest.approx(1.5)
    with pytest.raises(ValueError, match="empty"):
        aggregate([])
    with pytest.raises(ValueError, match="spl"):
        aggregate([{"success": 1.0, "collision_rate": 0.0}])
    with pytest.raises(ValueError, match="steps"):
        aggregate([a, {k: v for k, v in b.items() if k != "steps"}])  # no rate, no steps
    assert aggregate([b])["collision_rate"] == pytest.approx(0.25)


def test_format_table():
    table = format_table({"expert": {"success": 1.0, "episodes": 3}, "random": {"success": 0.0}})
    lines = table.splitlines()
    assert len(lines) == 4
    assert lines[0].split("|")[1:-1] == [" name   ", " success ", " episodes "]
    assert "1.000" in lines[2] and "| 3" in lines[2]
    assert lines[3].rstrip().endswith("-        |")  # missing key shown as '-'
    assert all(len(line) == len(lines[0]) for line in lines)
