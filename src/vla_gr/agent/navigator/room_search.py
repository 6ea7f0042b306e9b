"""Where to look first: the value of each map cell as a place to search for the goal, from the
types of room the robot has passed (``model.navigator.room_search``).

Every planner tick the room-type classifier says which type of room the robot stands in
(probabilities over ``room_types``); the cells within ``radius`` of the robot, reached through
seen free space (a wall stops it), add that evidence. A cell's room posterior is the mean of
what it received. Its value for a goal of category ``c``:

    value = sum_r posterior_r * presence[c][r]         (a cell with evidence)
    value = sum_r room_share_r * presence[c][r]        (a cell no tick has typed: unknown room)

where ``presence[c][r]`` is how often a room of type r holds a ``c`` and ``room_share`` how
common each type is, both learned from the training houses
(:mod:`vla_gr.training.room_prior`). A request that names a room ("the chair in the kitchen")
replaces ``presence[c]`` by that room's indicator times it. The field then plans to the
frontier cells worth at least ``keep`` times the best one first
(:meth:`vla_gr.core.gr_field.planning.GRField.update`'s ``frontier_value``): a kitchen the
robot has looked around is not searched again for a bed while a doorway to rooms it has not
seen is open.
"""

from __future__ import annotations

import numpy as np
import torch

from vla_gr.agent.navigator.config import RoomSearchConfig
from vla_gr.core.gr_field.physics import grow_through

__all__ = ["RoomSearch"]


class RoomSearch:
    """Room evidence on the navigator's grid and the search value of its cells.

    Args:
        config: ``model.navigator.room_search`` (enabled, with its learned tables).
        shape: (H, W) of the map grid.
        cell_size: metres per cell.
    """

    def __init__(self, config: RoomSearchConfig, shape: tuple[int, int], cell_size: float) -> None:
        self.config = config
        self.cell_size = float(cell_size)
        rooms = len(config.room_types)
        self.evidence = np.zeros((rooms, *shape), np.float32)  # (R, H, W) summed probabilities
        self.count = np.zeros(shape, np.float32)  # (H, W) ticks that typed each cell
        self.room_values: np.ndarray | None = None  # (R,) for this episode's goal
        self.unknown_value = 0.0
        self.room_index: int | None = None  # the instructed room's type (None: not named)

    def set_goal(self, category: str | None, room: str | None) -> None:
        """The goal of this episode (class names as read; None: not named). An unknown
        category (none in the learned table) leaves every cell worth the same."""
        c = self.config
        self.room_index = c.room_types.index(room) if room in c.room_types else None
        if category not in c.categories:
            self.room_values = None
            return
        values = np.asarray(c.presence[c.categories.index(category)], np.float64)  # (R,)
        if self.room_index is not None:
            values = values * (np.arange(len(values)) == self.room_index)
        self.room_values = values
        self.unknown_value = float(np.dot(c.room_share, values))

    def observe(
        self, room_probs: np.ndarray, robot_cell: tuple[int, int], free: np.ndarray
    ) -> None:
        """One tick: ``room_probs`` (R,) of the room the robot stands in, its cell (row, col),
        ``free`` (H, W) bool seen free cells the evidence may spread through."""
        if not self._on_map(robot_cell):
            return
        row, col = robot_cell
        H, W = free.shape
        seed = np.zeros((1, H, W), bool)
        seed[0, row, col] = True
        steps = int(np.ceil(self.config.radius / self.cell_size))
        passable = torch.from_numpy(free | seed[0])[None]  # (1, H, W)
        reached = grow_through(torch.from_numpy(seed), passable, steps)[0].numpy()  # (H, W)
        self.evidence[:, reached] += np.asarray(room_probs, np.float32)[:, None]
        self.count[reached] += 1.0

    def room_belief(self, cell: tuple[int, int]) -> float | None:
        """The mean probability, over every tick that typed ``cell`` (row, col), that it lies in
        a room of the instructed type; None when no room is named or no tick typed the cell."""
        if self.room_index is None or not self._on_map(cell) or self.count[cell] == 0:
            return None
        return float(self.evidence[self.room_index, cell[0], cell[1]] / self.count[cell])

    def _on_map(self, cell: tuple[int, int]) -> bool:
        """Whether ``cell`` (row, col) lies on the map's grid."""
        H, W = self.count.shape
        return 0 <= cell[0] < H and 0 <= cell[1] < W

    def value(self) -> np.ndarray | None:
        """(H, W) float32 search value of every cell for this episode's goal; None when the
        goal's category has no learned presence (every cell is then worth the same)."""
        if self.room_values is None:
            return None
        typed = self.count > 0  # (H, W)
        out = np.full(self.count.shape, self.unknown_value, np.float32)  # (H, W)
        posterior = self.evidence[:, typed] / self.count[typed]  # (R, N)
        out[typed] = self.room_values @ posterior  # (N,)
        return out
