"""Furniture placement inside rooms: what goes where, against walls or around anchors.

Rules follow real homes: toilets only in bathrooms, beds only in bedrooms, sofas and tvs in
living rooms, chairs around tables, nightstands beside beds, a tv facing the sofa or bed.
Pieces never overlap each other, stay inside their room and leave a clear zone in front of
every door. Reachability is checked afterwards on the occupancy grid (``house.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vla_gr.envs.floorplan import door_clear_zones
from vla_gr.envs.furniture import PALETTES, sample_dimensions
from vla_gr.envs.scene import Door, ObjectInstance, Room

_WALL_GAP = 0.02  # between a piece's back and the wall
_OBJECT_GAP = 0.05  # minimum gap between two pieces
_FREE_CLEARANCE = 0.55  # free-standing pieces keep this much room to every wall
_ATTEMPTS = 25

#: Yaw that puts a piece's back (local -y) against each wall side.
SIDE_YAW = {"s": 0.0, "e": np.pi / 2, "n": np.pi, "w": -np.pi / 2}
_OPPOSITE = {"s": "n", "n": "s", "e": "w", "w": "e"}


@dataclass(frozen=True)
class Item:
    """One line of a room's furniture list: ``lo``..``hi`` pieces placed by ``mode``."""

    category: str
    lo: int
    hi: int
    mode: str = "wall"  # wall | free | around:<cat> | front:<cat> | beside:<cat> | opposite:<cat>
    essential: bool = False


#: What each room type holds, in placement order (large, defining pieces first).
ROOM_FURNITURE: dict[str, tuple[Item, ...]] = {
    "living_room": (
        Item("sofa", 1, 2, "wall", essential=True),
        Item("tv_monitor", 1, 1, "opposite:sofa", essential=True),
        Item("table", 0, 1, "free"),
        Item("chair", 1, 2, "around:table"),
        Item("plant", 1, 2, "wall"),
        Item("cabinet", 0, 1, "wall"),
    ),
    "bedroom": (
        Item("bed", 1, 1, "wall", essential=True),
        Item("cabinet", 1, 2, "beside:bed"),
        Item("tv_monitor", 0, 1, "opposite:bed"),
        Item("cabinet", 0, 1, "wall"),
        Item("chair", 0, 1, "wall"),
        Item("plant", 0, 1, "wall"),
    ),
    "kitchen": (
        Item("table", 1, 1, "free", essential=True),
        Item("chair", 2, 4, "around:table"),
        Item("cabinet", 2, 3, "wall"),
        Item("plant", 0, 1, "wall"),
    ),
    "bathroom": (
        Item("toilet", 1, 1, "wall", essential=True),
        Item("cabinet", 0, 1, "wall"),
        Item("plant", 0, 1, "wall"),
    ),
    "office": (
        Item("table", 1, 1, "wall", essential=True),
        Item("chair", 1, 1, "front:table"),
        Item("tv_monitor", 0, 1, "wall"),
        Item("cabinet", 1, 2, "wall"),
        Item("sofa", 0, 1, "wall"),
        Item("plant", 0, 1, "wall"),
    ),
    "hallway": (
        Item("plant", 1, 2, "wall"),
        Item("cabinet", 0, 1, "wall"),
        Item("chair", 0, 1, "wall"),
    ),
}

#: Goal categories topped up (in rooms that may hold them) so that distractors exist.
TOP_UP = {"chair": 3, "plant": 2}


@dataclass
class Placed:
    """A placed piece with its placement bookkeeping."""

    obj: ObjectInstance
    essential: bool
    side: str | None  # wall side its back is against, if any

    @property
    def corners(self) -> np.ndarray:
        """Footprint corners (4, 2), computed once."""
        if not hasattr(self, "_corners"):
            self._corners = self.obj.footprint()
        return self._corners


def rect_corners(x: float, y: float, yaw: float, hx: float, hy: float) -> np.ndarray:
    """Corners (4, 2) of an oriented rectangle, counter-clockwise."""
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    c, s = np.cos(yaw), np.sin(yaw)
    return local @ np.array([[c, s], [-s, c]]) + np.array([x, y])


def rects_overlap(a: np.ndarray, b: np.ndarray, gap: float = 0.0) -> bool:
    """Separating-axis test for convex quads ``a``, ``b`` (4, 2); ``gap`` pads the test."""
    for quad in (a, b):
        for k in range(4):
            edge = quad[(k + 1) % 4] - quad[k]
            axis = np.array([-edge[1], edge[0]]) / np.hypot(*edge)
            pa, pb = a @ axis, b @ axis
            if pa.max() + gap <= pb.min() or pb.max() + gap <= pa.min():
                return False
    return True


def _inside(corners: np.ndarray, room: Room, margin: float) -> bool:
    return bool(
        corners[:, 0].min() >= room.x0 + margin - 1e-9
        and corners[:, 0].max() <= room.x1 - margin + 1e-9
        and corners[:, 1].min() >= room.y0 + margin - 1e-9
        and corners[:, 1].max() <= room.y1 - margin + 1e-9
    )


class RoomPlacer:
    """Places pieces in one room, avoiding door zones and pieces already placed."""

    def __init__(self, room: Room, doors: list[Door], placed: list[Placed]) -> None:
        self.room = room
        self.placed = placed
        self.zones = [
            np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
            for x0, y0, x1, y1 in door_clear_zones(room, doors)
        ]

    def fits(self, corners: np.ndarray, margin: float = 0.0) -> bool:
        """Whether a footprint (4, 2) lies in the room, off door zones and other pieces."""
        if not _inside(corners, self.room, margin):
            return False
        lo, hi = corners.min(0), corners.max(0)
        for zone in self.zones:  # door zones are axis-aligned: a box test is exact
            if (zone.min(0) < hi).all() and (zone.max(0) > lo).all():
                return False
        lo, hi = lo - _OBJECT_GAP, hi + _OBJECT_GAP
        for p in self.placed:
            if p.obj.room_index != self.room.index:
                continue  # rooms do not overlap
            other = p.corners
            if (other.min(0) >= hi).any() or (other.max(0) <= lo).any():
                continue  # bounding boxes already apart by the gap
            if rects_overlap(corners, other, _OBJECT_GAP):
                return False
        return True

    def wall_pose(self, side: str, along: float, hx: float, hy: float):
        """(x, y, yaw) of a piece with its back against wall ``side`` at coordinate ``along``."""
        r = self.room
        off = hy + _WALL_GAP
        return {
            "s": (along, r.y0 + off, SIDE_YAW["s"]),
            "n": (along, r.y1 - off, SIDE_YAW["n"]),
            "w": (r.x0 + off, along, SIDE_YAW["w"]),
            "e": (r.x1 - off, along, SIDE_YAW["e"]),
        }[side]

    def along_range(self, side: str, hx: float) -> tuple[float, float]:
        r = self.room
        lo, hi = (r.x0, r.x1) if side in ("s", "n") else (r.y0, r.y1)
        return lo + hx + _WALL_GAP, hi - hx - _WALL_GAP

    def anchors(self, category: str) -> list[Placed]:
        return [
            p
            for p in self.placed
            if p.obj.category == category and p.obj.room_index == self.room.index
        ]

    def propose(self, mode: str, hx: float, hy: float, rng: np.random.Generator):
        """One candidate pose (x, y, yaw, side) for ``mode``, or None if it cannot apply."""
        kind, _, anchor_cat = mode.partition(":")
        anchors = self.anchors(anchor_cat) if anchor_cat else []
        if anchor_cat and not anchors:
            kind = "wall"
        if kind == "wall":
            side = str(rng.choice(list(SIDE_YAW)))
            lo, hi = self.along_range(side, hx)
            if hi < lo:
                return None
            # Plants and cabinets like corners.
            along = (
                rng.uniform(lo, hi) if rng.random() < 0.6 else (lo if rng.random() < 0.5 else hi)
            )
            return (*self.wall_pose(side, along, hx, hy), side)
        if kind == "free":
            r, ext = self.room, max(hx, hy) + _FREE_CLEARANCE
            if r.x1 - r.x0 < 2 * ext or r.y1 - r.y0 < 2 * ext:
                return None
            yaw = float(rng.choice([0.0, np.pi / 2]))
            return (
                rng.uniform(r.x0 + ext, r.x1 - ext),
                rng.uniform(r.y0 + ext, r.y1 - ext),
                yaw,
                None,
            )
        anchor = anchors[int(rng.integers(len(anchors)))]
        a = anchor.obj
        ahx, ahy = a.half_extents
        if kind == "opposite" and anchor.side is not None:
            side = _OPPOSITE[anchor.side]
            lo, hi = self.along_range(side, hx)
            if hi < lo:
                return None
            centre = a.x if side in ("s", "n") else a.y
            along = float(np.clip(centre + rng.normal(0.0, 0.3), lo, hi))
            return (*self.wall_pose(side, along, hx, hy), side)
        if kind == "beside" and anchor.side is not None:
            sign = 1.0 if rng.random() < 0.5 else -1.0
            local = np.array([sign * (ahx + hx + _OBJECT_GAP + 0.02), -ahy + hy])
        elif kind in ("around", "front", "opposite", "beside"):
            sides = ["front"] if kind == "front" else ["front", "back", "left", "right"]
            which = sides[int(rng.integers(len(sides)))]
            dist_y, dist_x = ahy + hy + _OBJECT_GAP + 0.03, ahx + hy + _OBJECT_GAP + 0.03
            u = rng.uniform(-max(ahx - hx, 0.0), max(ahx - hx, 0.0))
            v = rng.uniform(-max(ahy - hx, 0.0), max(ahy - hx, 0.0))
            local, turn = {
                "front": (np.array([u, dist_y]), np.pi),
                "back": (np.array([u, -dist_y]), 0.0),
                "left": (np.array([-dist_x, v]), -np.pi / 2),
                "right": (np.array([dist_x, v]), np.pi / 2),
            }[which]
            c, s = np.cos(a.yaw), np.sin(a.yaw)
            x, y = a.x + c * local[0] - s * local[1], a.y + s * local[0] + c * local[1]
            return x, y, float(np.arctan2(np.sin(a.yaw + turn), np.cos(a.yaw + turn))), None
        else:
            return None
        c, s = np.cos(a.yaw), np.sin(a.yaw)
        x, y = a.x + c * local[0] - s * local[1], a.y + s * local[0] + c * local[1]
        return x, y, a.yaw, anchor.side

    def place(self, mode: str, hx: float, hy: float, rng: np.random.Generator):
        """Try ``_ATTEMPTS`` candidates; return the first pose that fits, else None."""
        for _ in range(_ATTEMPTS):
            pose = self.propose(mode, hx, hy, rng)
            if pose is None:
                continue
            x, y, yaw, side = pose
            if self.fits(rect_corners(x, y, yaw, hx, hy)):
                return float(x), float(y), float(yaw), side
        return None


def _pick_color(category: str, used: dict[str, list[str]], rng: np.random.Generator) -> str:
    """A colour of the category's palette not used yet by that category (if any is left)."""
    palette = list(PALETTES[category])
    fresh = [c for c in palette if c not in used.setdefault(category, [])]
    color = str(rng.choice(fresh or palette))
    used[category].append(color)
    return color


def place_furniture(
    rooms: list[Room], doors: list[Door], clutter: float, rng: np.random.Generator
) -> list[Placed]:
    """Furniture for every room; ``clutter`` scales how many optional pieces are drawn."""
    placed: list[Placed] = []
    used: dict[str, list[str]] = {}

    def add(room: Room, item: Item, placer: RoomPlacer, mode: str) -> bool:
        hx, hy, height = sample_dimensions(item.category, rng)
        if mode.startswith("beside:"):  # nightstand-sized
            hx, hy, height = min(hx, 0.28), min(hy, 0.22), min(height, 0.65)
        pose = placer.place(mode, hx, hy, rng)
        if pose is None:
            return False
        x, y, yaw, side = pose
        obj = ObjectInstance(
            instance_id=len(placed) + 1,
            category=item.category,
            color=_pick_color(item.category, used, rng),
            room_index=room.index,
            x=round(x, 4),
            y=round(y, 4),
            yaw=yaw,
            half_extents=(hx, hy),
            height=height,
        )
        placed.append(Placed(obj, item.essential, side))
        return True

    placers = {room.index: RoomPlacer(room, doors, placed) for room in rooms}
    for room in rooms:
        for item in ROOM_FURNITURE[room.room_type]:
            count = int(round(int(rng.integers(item.lo, item.hi + 1)) * clutter))
            if item.essential:
                count = max(count, 1)
            for _ in range(count):
                add(room, item, placers[room.index], item.mode)

    if clutter > 0:
        for category, minimum in TOP_UP.items():
            hosts = [
                r for r in rooms if any(i.category == category for i in ROOM_FURNITURE[r.room_type])
            ]
            for _ in range(3 * minimum):
                if sum(p.obj.category == category for p in placed) >= minimum or not hosts:
                    break
                room = hosts[int(rng.integers(len(hosts)))]
                add(room, Item(category, 1, 1), placers[room.index], "wall")
    return placed
