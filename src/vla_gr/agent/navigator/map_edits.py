"""The navigator's edits of its GR field's map, made through the field's own methods
(``add_obstacle_evidence``, ``forget_obstacle_noise``, ``mark_unseen_free``): obstacles it adds,
noise it forgets, cells it counts as seen.

- virtual obstacles: evidence added in front of a blocked robot so that the path bends around
  what the camera cannot see; forgotten together when no path is left (they may close a door);
- lasting obstacles: the same, never forgotten (a trapped robot closes the way ahead for good);
- noise: obstacle cells with a few hits that free space outvotes (grazing points of a door
  jamb) are dropped, so that one stray point never closes a door for good;
- visited: unseen cells around the robot count as seen free, so frontiers in the camera's blind
  spots cannot pull the robot back and forth.

Its settings are ``model.navigator.map_edits``
(:class:`~vla_gr.agent.navigator.config.MapEditsConfig`).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from vla_gr.agent.navigator.config import MapEditsConfig
from vla_gr.core.gr_field.mapping import points_to_cells
from vla_gr.core.gr_field.planning import GRField

__all__ = ["MapEdits"]


class MapEdits:
    """Edits of ``field``'s batch-1 map with the settings ``config`` (``model.navigator.map_edits``:
    ``obstacle_hits``, ``noise_max_hits``, ``noise_free_ratio``, ``visited_clear_radius``)."""

    def __init__(self, field: GRField, config: MapEditsConfig) -> None:
        self.field, self.config = field, config
        self.virtual: list[torch.Tensor] = []  # (D, 2) cells of each virtual obstacle

    def disk_cells(self, xy: np.ndarray, radius: float) -> torch.Tensor:
        """Cells (D, 2) as (row, col) within ``radius`` of map-frame point ``xy`` (2,)."""
        h = self.field.grid.cell_size
        k = int(math.ceil(radius / h))
        offs = np.arange(-k, k + 1) * h
        dx, dy = np.meshgrid(offs, offs)
        disk = dx**2 + dy**2 <= radius**2
        pts = torch.tensor(np.stack([dx[disk], dy[disk]], -1) + xy, dtype=torch.float32)
        cells, inside = points_to_cells(pts, self.field.grid)  # (D, 2), (D,)
        return cells[inside]

    def mark_obstacle(self, xy: np.ndarray, radius: float, lasting: bool = False) -> None:
        """Add obstacle evidence to the cells within ``radius`` of map-frame point ``xy`` (2,);
        a virtual obstacle is forgotten when no path is left, a ``lasting`` one never."""
        cells = self.disk_cells(xy, radius)  # (D, 2)
        if self.field.batch_size == 0 or len(cells) == 0:
            return
        self.field.add_obstacle_evidence(cells, self.config.obstacle_hits)
        if not lasting:
            self.virtual.append(cells)

    def clear_virtual_obstacles(self) -> None:
        """Take back the evidence of every virtual obstacle (seen obstacles stay)."""
        for cells in self.virtual:
            self.field.add_obstacle_evidence(cells, -self.config.obstacle_hits)
        self.virtual.clear()

    def forget_noise(self) -> None:
        """Drop obstacle evidence that free-space evidence outvotes (see ``noise_*``)."""
        if self.field.batch_size == 0:
            return
        self.field.forget_obstacle_noise(self.config.noise_max_hits, self.config.noise_free_ratio)

    def mark_visited(self, xy: np.ndarray) -> None:
        """Count the unseen cells within ``visited_clear_radius`` of ``xy`` (2,) as seen free
        (one hit).

        Obstacle evidence still wins over it, so a cell seen occupied stays occupied.
        """
        radius = self.config.visited_clear_radius
        if radius <= 0 or self.field.batch_size == 0:
            return
        self.field.mark_unseen_free(self.disk_cells(xy, radius))  # (D, 2) cells
