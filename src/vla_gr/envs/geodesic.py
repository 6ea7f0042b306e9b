"""Ground-truth geodesic distances for the task: distance-to-goal fields and l* for SPL."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from vla_gr.envs.scene import House
from vla_gr.geometry import GridSpec, geodesic_distance, inflate_obstacles
from vla_gr.geometry.robot_spec import ROBOT_RADIUS


def clearance_radius(robot_radius: float, cell_size: float) -> float:
    """Inflation radius (m) that keeps a round robot clear of every occupied *cell*.

    Occupancy marks cells whose centre lies inside an obstacle, so an obstacle's true edge
    can reach half a cell beyond its outermost occupied centre; inflating by the radius
    alone would declare gaps up to one cell narrower than the robot passable.
    """
    return robot_radius + 0.5 * cell_size


def traversable_cells(house: House, robot_radius: float = ROBOT_RADIUS) -> np.ndarray:
    """(H, W) bool: cells where the robot's centre fits (occupancy inflated by clearance)."""
    radius = clearance_radius(robot_radius, house.grid.cell_size)
    return ~inflate_obstacles(house.occupancy, radius, house.grid.cell_size)


def goal_distance_field(
    house: House, instance_id: int, robot_radius: float = ROBOT_RADIUS
) -> np.ndarray:
    """Geodesic distance (H, W) in metres from the goal object's footprint, for robot centres.

    The front starts on the object's footprint and moves through cells where the robot's
    centre fits given every other obstacle; cells the robot cannot reach are ``inf``. The
    value at the robot's centre is the distance its centre must still travel to touch the
    footprint's boundary (Habitat's ObjectNav measures to the goal's view points; here to
    the footprint).
    """
    footprint = house.object_ids == instance_id  # (H, W)
    if not footprint.any():
        raise ValueError(f"object {instance_id} has no footprint cells in house {house.seed}")
    # Inflate every obstacle except the goal itself: the ring within the robot radius of the
    # goal is where the front leaves the footprint, so it must stay open.
    others = house.occupancy & ~footprint  # (H, W)
    radius = clearance_radius(robot_radius, house.grid.cell_size)
    blocked = inflate_obstacles(others, radius, house.grid.cell_size)  # (H, W)
    return geodesic_distance(1.0, footprint, blocked & ~footprint, house.grid.cell_size)


def sample_field(field: np.ndarray, grid: GridSpec, x: float, y: float) -> float:
    """Bilinear value of ``field`` (H, W) at world point (x, y); inf if any corner is inf."""
    fc = (x - grid.origin_x) / grid.cell_size - 0.5
    fr = (y - grid.origin_y) / grid.cell_size - 0.5
    r0, c0 = int(np.floor(fr)), int(np.floor(fc))
    if not (0 <= r0 < grid.height - 1 and 0 <= c0 < grid.width - 1):
        r = int(np.clip(round(fr), 0, grid.height - 1))
        c = int(np.clip(round(fc), 0, grid.width - 1))
        return float(field[r, c])
    patch = field[r0 : r0 + 2, c0 : c0 + 2]  # (2, 2)
    finite = np.isfinite(patch)
    if not finite.all():
        if not finite.any():
            return float("inf")
        # Near an obstacle edge: use the nearest finite corner rather than returning inf.
        ar, ac = fr - r0, fc - c0
        weights = np.array([[(1 - ar) * (1 - ac), (1 - ar) * ac], [ar * (1 - ac), ar * ac]])
        weights = np.where(finite, weights + 1e-9, 0.0)
        return float((np.where(finite, patch, 0.0) * weights).sum() / weights.sum())
    ar, ac = fr - r0, fc - c0
    top = patch[0, 0] * (1 - ac) + patch[0, 1] * ac
    bottom = patch[1, 0] * (1 - ac) + patch[1, 1] * ac
    return float(top * (1 - ar) + bottom * ar)


def connected_to(traversable: np.ndarray, cell: tuple[int, int]) -> np.ndarray:
    """(H, W) bool component of ``traversable`` (8-connected) containing ``cell``."""
    labels, _ = ndimage.label(traversable, structure=np.ones((3, 3), int))
    label = labels[cell]
    return labels == label if label > 0 else np.zeros_like(traversable)


def distance_at(field: np.ndarray, grid: GridSpec, x: float, y: float) -> float:
    """``field`` at (x, y), snapped to the nearest finite cell when the point has none.

    A robot centre inside the inflated margin (pressed against a wall) samples only ``inf``
    corners; like Habitat, which snaps such a position to the nearest navigable point, the
    value of the nearest cell with a finite distance is returned instead (``inf`` only when
    the field has no finite cell at all).
    """
    value = sample_field(field, grid, x, y)
    if np.isfinite(value):
        return value
    rows, cols = np.nonzero(np.isfinite(field))
    if rows.size == 0:
        return float("inf")
    centres = grid.cell_to_world(np.stack([rows, cols], axis=-1))  # (N, 2)
    nearest = int(np.argmin(np.sum((centres - np.array([x, y])) ** 2, axis=1)))
    return float(field[rows[nearest], cols[nearest]])
