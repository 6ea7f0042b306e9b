"""Plain data describing a generated house: rooms, doors, objects, occupancy.

This is the contract between ``house.py`` (which builds it), the environment (which
simulates and renders it), the expert/metrics (which measure on its occupancy grid)
and the pictures. Coordinates are world metres, x east, y north, yaw counter-clockwise
from +x.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vla_gr.geometry import GridSpec

#: Object categories that can be built; the first six are HM3D's ObjectNav goal set.
GOAL_CATEGORIES: tuple[str, ...] = ("chair", "sofa", "bed", "toilet", "tv_monitor", "plant")
CATEGORIES: tuple[str, ...] = GOAL_CATEGORIES + ("table", "cabinet")

#: Named colours (RGB in [0, 1]) used for furniture; instructions use these names.
COLORS: dict[str, tuple[float, float, float]] = {
    "red": (0.80, 0.12, 0.12),
    "blue": (0.15, 0.30, 0.85),
    "green": (0.15, 0.65, 0.20),
    "yellow": (0.92, 0.82, 0.15),
    "white": (0.93, 0.93, 0.93),
    "black": (0.08, 0.08, 0.08),
    "orange": (0.95, 0.50, 0.10),
    "purple": (0.55, 0.20, 0.70),
}

ROOM_TYPES: tuple[str, ...] = ("kitchen", "living_room", "bedroom", "bathroom", "office", "hallway")


def room_display_name(room_type: str) -> str:
    """'living_room' -> 'living room' (how instructions say it)."""
    return room_type.replace("_", " ")


def category_display_name(category: str) -> str:
    """'tv_monitor' -> 'tv' (how instructions say it)."""
    return {"tv_monitor": "tv"}.get(category, category.replace("_", " "))


@dataclass(frozen=True)
class Room:
    """An axis-aligned rectangular room: [x0, x1] x [y0, y1] (interior, metres)."""

    index: int
    room_type: str
    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def polygon(self) -> np.ndarray:
        """Corners (4, 2) counter-clockwise."""
        return np.array(
            [[self.x0, self.y0], [self.x1, self.y0], [self.x1, self.y1], [self.x0, self.y1]]
        )

    def contains(self, x: float, y: float) -> bool:
        return self.x0 <= x <= self.x1 and self.y0 <= y <= self.y1


@dataclass(frozen=True)
class Door:
    """An opening in a wall between two rooms; ``axis`` is the wall's direction ('x' or 'y')."""

    room_a: int
    room_b: int
    x: float
    y: float
    width: float
    axis: str


@dataclass(frozen=True)
class ObjectInstance:
    """One piece of furniture. ``instance_id`` >= 1 is its id in segmentation images."""

    instance_id: int
    category: str
    color: str
    room_index: int
    x: float
    y: float
    yaw: float
    half_extents: tuple[float, float]  # footprint half sizes along the object's own x, y
    height: float

    @property
    def body_name(self) -> str:
        """Name of the MJCF body holding every geom of this object."""
        return f"obj{self.instance_id}"

    def footprint(self) -> np.ndarray:
        """Corners (4, 2) of the oriented footprint rectangle, counter-clockwise."""
        hx, hy = self.half_extents
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        rot = np.array([[c, -s], [s, c]])
        return local @ rot.T + np.array([self.x, self.y])


@dataclass
class House:
    """A generated house. Fully determined by ``seed`` (and the generation knobs).

    ``occupancy`` (H, W) bool marks every cell whose centre lies inside a wall or an
    object footprint (anything the robot base can hit); ``object_ids`` (H, W) int32 gives
    the instance id whose footprint covers a cell (0 elsewhere).
    """

    seed: int
    rooms: list[Room]
    doors: list[Door]
    objects: list[ObjectInstance]
    grid: GridSpec
    occupancy: np.ndarray
    object_ids: np.ndarray
    wall_height: float = 2.5
    meta: dict = field(default_factory=dict)

    def object(self, instance_id: int) -> ObjectInstance:
        for obj in self.objects:
            if obj.instance_id == instance_id:
                return obj
        raise KeyError(f"house {self.seed} has no object with instance_id={instance_id}")

    def room_of(self, x: float, y: float) -> Room | None:
        for room in self.rooms:
            if room.contains(x, y):
                return room
        return None
