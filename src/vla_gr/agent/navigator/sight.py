"""What the robot can see on its map: straight lines between cells that no obstacle cuts, and
the nearest goal cell in sight (the navigator's approach distance)."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["line_of_sight", "nearest_goal_in_sight"]


def line_of_sight(a: np.ndarray, b: np.ndarray, occupied: np.ndarray, cell_size: float) -> bool:
    """No ``occupied`` (H, W) cell on the segment ``a`` -> ``b`` (2,) (metric x, y from the
    grid's lower-left corner), sampled every half cell, ends included."""
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / (0.5 * cell_size))) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]  # (n, 1)
    rc = np.floor((a[None] * (1 - t) + b[None] * t)[:, ::-1] / cell_size).astype(int)  # (n, 2)
    return not occupied[rc[:, 0], rc[:, 1]].any()


def nearest_goal_in_sight(
    goal_cells: np.ndarray,
    robot_xy: np.ndarray,
    occupied: np.ndarray,
    cell_size: float,
    halo_cells: int,
    candidates: int = 8,
) -> tuple[float, np.ndarray | None]:
    """Distance (m) from ``robot_xy`` (2,) to the nearest centre of ``goal_cells`` (H, W) bool
    that an ``occupied`` (H, W) cell does not hide, and that centre (2,).

    Occupied cells within ``halo_cells`` of the goal are the goal's own body and hide nothing;
    of the ``candidates`` nearest centres, the first in sight wins. None in sight: (inf, the
    nearest centre); no goal cell: (inf, None).
    """
    if not goal_cells.any():
        return math.inf, None
    rows, cols = np.nonzero(goal_cells)
    centres = (np.stack([cols, rows], axis=-1) + 0.5) * cell_size  # (M, 2) x, y from the corner
    dist = np.linalg.norm(centres - robot_xy, axis=-1)  # (M,)
    near_goal = ndimage.binary_dilation(goal_cells, iterations=halo_cells)  # (H, W)
    walls = occupied & ~near_goal  # (H, W)
    for k in np.argsort(dist)[:candidates]:
        if line_of_sight(robot_xy, centres[k], walls, cell_size):
            return float(dist[k]), centres[k]
    k = int(np.argmin(dist))
    return math.inf, centres[k]
