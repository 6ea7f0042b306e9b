"""Line of sight on the map and the nearest goal cell in sight, on hand-drawn grids."""

from __future__ import annotations

import math

import numpy as np

from vla_gr.agent.navigator.sight import line_of_sight, nearest_goal_in_sight

H = 0.1  # metres per cell


def centre(row: int, col: int) -> np.ndarray:
    return (np.array([col, row]) + 0.5) * H


def test_a_wall_between_two_cells_cuts_the_line_and_one_beside_it_does_not():
    occupied = np.zeros((10, 10), bool)
    occupied[2:8, 5] = True  # a wall in column 5, rows 2-7
    assert not line_of_sight(centre(4, 1), centre(4, 8), occupied, H)
    assert line_of_sight(centre(9, 1), centre(9, 8), occupied, H)  # passes below the wall
    assert line_of_sight(centre(4, 1), centre(4, 4), occupied, H)  # stops short of it


def test_the_nearest_goal_cell_behind_a_wall_gives_way_to_one_in_sight():
    goal = np.zeros((12, 12), bool)
    goal[5, 3] = True  # 3 cells from the robot, behind a wall
    goal[5, 10] = True  # 4 cells away, in the open
    occupied = np.zeros((12, 12), bool)
    occupied[3:8, 5] = True  # a wall in column 5, two cells from the near goal cell
    robot = centre(5, 6)
    distance, seen = nearest_goal_in_sight(goal, robot, occupied, H, halo_cells=1)
    assert np.allclose(seen, centre(5, 10)) and math.isclose(distance, 4 * H)
    # the goal's own body (within the halo) hides nothing: with a halo of 2 the wall is
    # part of the near goal cell's body, and that cell wins
    distance, seen = nearest_goal_in_sight(goal, robot, occupied, H, halo_cells=2)
    assert np.allclose(seen, centre(5, 3)) and math.isclose(distance, 3 * H)


def test_no_goal_in_sight_gives_inf_and_the_nearest_centre_and_no_goal_gives_none():
    goal = np.zeros((8, 8), bool)
    goal[1, 1] = True
    occupied = np.zeros((8, 8), bool)
    occupied[0:8, 3] = True  # a wall across the grid
    distance, seen = nearest_goal_in_sight(goal, centre(1, 6), occupied, H, halo_cells=1)
    assert distance == math.inf and np.allclose(seen, centre(1, 1))
    assert nearest_goal_in_sight(np.zeros((8, 8), bool), centre(1, 6), occupied, H, 1) == (
        math.inf,
        None,
    )
