import numpy as np
import pytest

from vla_gr.envs.geodesic import ROBOT_RADIUS, goal_distance_field, sample_field
from vla_gr.envs.scene import House, ObjectInstance, Room
from vla_gr.geometry import GridSpec


def _room_with_box(cell: float = 0.05) -> House:
    """A 4 x 4 m walled room with one 0.4 x 0.4 m box centred at (2, 2)."""
    grid = GridSpec(0.0, 0.0, cell, 80, 80)
    occ = np.zeros(grid.shape, bool)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = True  # walls 0.1 m thick
    ids = np.zeros(grid.shape, np.int32)
    ids[36:44, 36:44] = 1  # footprint [1.8, 2.2]^2
    occ |= ids > 0
    box = ObjectInstance(1, "chair", "red", 0, 2.0, 2.0, 0.0, (0.2, 0.2), 0.8)
    return House(0, [Room(0, "office", 0.1, 0.1, 3.9, 3.9)], [], [box], grid, occ, ids)


def test_goal_distance_is_distance_to_footprint_edge():
    house = _room_with_box()
    field = goal_distance_field(house, 1)  # (H, W)
    # straight out along +x from the box's right edge (x = 2.2) at its centre line y = 2.0
    for x in (2.5, 3.0, 3.5):
        assert sample_field(field, house.grid, x, 2.0) == pytest.approx(x - 2.2, abs=0.05)
    # the ring around the goal (closer than the robot radius) is reachable, not inf
    assert np.isfinite(sample_field(field, house.grid, 2.2 + 0.5 * ROBOT_RADIUS, 2.0))
    # the walls' inflation band stays blocked
    assert np.isinf(field[3, 40])


def test_missing_goal_raises():
    with pytest.raises(ValueError, match="no footprint"):
        goal_distance_field(_room_with_box(), 7)


def test_distance_inside_the_inflated_margin_snaps_to_the_nearest_navigable_cell():
    from vla_gr.envs.geodesic import distance_at

    house = _room_with_box()
    field = goal_distance_field(house, 1)  # (H, W)
    x, y = 0.16, 2.0  # centre closer to the left wall than the robot radius
    assert np.isinf(sample_field(field, house.grid, x, y))
    snapped = distance_at(field, house.grid, x, y)
    assert np.isfinite(snapped)
    # the nearest navigable cell lies just right of the margin, at the same height
    edge = next(c for c in range(80) if np.isfinite(field[40, c]))
    assert snapped == pytest.approx(field[40, edge], abs=0.06)
    # where the sample is finite, nothing changes
    assert distance_at(field, house.grid, 3.0, 2.0) == sample_field(field, house.grid, 3.0, 2.0)
    assert np.isinf(distance_at(np.full((80, 80), np.inf), house.grid, x, y))
