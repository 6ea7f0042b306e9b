"""Top-down metric grids: world <-> cell conversion and obstacle inflation.

Convention: a grid covers the rectangle starting at ``origin`` (x, y of the
lower-left corner, metres); cell ``(row, col)`` has its centre at
``(origin_x + (col + 0.5) * cell_size, origin_y + (row + 0.5) * cell_size)``.
Rows grow with +y, columns with +x, so ``grid[row, col]`` reads like ``grid[y, x]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class GridSpec:
    """Placement of a 2-D grid in the world plane."""

    origin_x: float
    origin_y: float
    cell_size: float
    height: int  # rows (y)
    width: int  # cols (x)

    def __post_init__(self) -> None:
        if self.cell_size <= 0:
            raise ValueError(f"GridSpec.cell_size must be > 0, got {self.cell_size}")
        if self.height <= 0 or self.width <= 0:
            raise ValueError(f"GridSpec shape must be positive, got {(self.height, self.width)}")

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """Metric points (..., 2) as (x, y) -> integer cells (..., 2) as (row, col)."""
        xy = np.asarray(xy, dtype=np.float64)
        col = np.floor((xy[..., 0] - self.origin_x) / self.cell_size)
        row = np.floor((xy[..., 1] - self.origin_y) / self.cell_size)
        return np.stack([row, col], axis=-1).astype(np.int64)

    def cell_to_world(self, rc: np.ndarray) -> np.ndarray:
        """Cells (..., 2) as (row, col) -> metric centres (..., 2) as (x, y)."""
        rc = np.asarray(rc, dtype=np.float64)
        x = self.origin_x + (rc[..., 1] + 0.5) * self.cell_size
        y = self.origin_y + (rc[..., 0] + 0.5) * self.cell_size
        return np.stack([x, y], axis=-1)

    def in_bounds(self, rc: np.ndarray) -> np.ndarray:
        """Boolean (...,) mask of cells inside the grid."""
        rc = np.asarray(rc)
        return (
            (rc[..., 0] >= 0)
            & (rc[..., 0] < self.height)
            & (rc[..., 1] >= 0)
            & (rc[..., 1] < self.width)
        )

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Metric x (H, W) and y (H, W) of every cell centre."""
        xs = self.origin_x + (np.arange(self.width) + 0.5) * self.cell_size
        ys = self.origin_y + (np.arange(self.height) + 0.5) * self.cell_size
        return np.meshgrid(xs, ys)  # each (H, W)


def disk_kernel(radius: float, cell_size: float) -> np.ndarray:
    """Boolean disk (2k+1, 2k+1) of cells whose centres lie within ``radius`` of the centre."""
    k = int(np.ceil(radius / cell_size))
    offsets = np.arange(-k, k + 1) * cell_size
    dx, dy = np.meshgrid(offsets, offsets)
    return dx**2 + dy**2 <= radius**2 + 1e-12


def inflate_obstacles(occupancy: np.ndarray, radius: float, cell_size: float) -> np.ndarray:
    """Cells (H, W) whose centre is closer than ``radius`` to an obstacle cell's centre.

    Exact Euclidean inflation via a distance transform: a free cell stays free only if a
    disk of ``radius`` around its centre touches no occupied cell centre. Used to turn a
    map into the configuration space of a round robot.
    """
    occupancy = np.asarray(occupancy, dtype=bool)
    if radius <= 0 or not occupancy.any():
        return occupancy.copy()
    distance = ndimage.distance_transform_edt(~occupancy) * cell_size  # (H, W) metres
    return distance <= radius
