"""Floorplans: rooms laid out in one or two rows, doors between them, and wall boxes.

Rooms are interior rectangles separated by walls of thickness ``WALL_THICKNESS``: two
neighbouring rooms are exactly one wall apart. Walls are derived from rooms and doors by a
pure function (:func:`wall_boxes`), so hand-built houses get walls the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vla_gr.envs.scene import Door, Room

WALL_THICKNESS = 0.1
WALL_HEIGHT = 2.5
DOOR_HEIGHT = 2.1
DOOR_MARGIN = 0.3  # min distance from a door's edge to a wall corner
_TOL = 1e-6

#: Row splits of N rooms (rooms per row, south row first).
_ROW_SPLITS: dict[int, tuple[tuple[int, ...], ...]] = {
    1: ((1,),),
    2: ((2,), (1, 1)),
    3: ((3,), (2, 1), (1, 2)),
    4: ((2, 2), (3, 1), (1, 3)),
    5: ((3, 2), (2, 3)),
    6: ((3, 3),),
}


@dataclass(frozen=True)
class WallBox:
    """An axis-aligned wall box [x0, x1] x [y0, y1] x [z0, z1]; ``room`` -1 means exterior."""

    name: str
    x0: float
    y0: float
    x1: float
    y1: float
    z0: float
    z1: float
    room: int

    @property
    def blocks_robot(self) -> bool:
        """Whether the box reaches down to robot height (lintels above doors do not)."""
        return self.z0 < 0.4


def _q(value: float) -> float:
    """Round to 5 cm so room edges never fall on 5 cm cell centres."""
    return round(round(value / 0.05) * 0.05, 4)


def sample_room_types(num_rooms: int, rng: np.random.Generator) -> list[str]:
    """Room types for ``num_rooms`` rooms: one living room, then a varied mix."""
    if num_rooms == 1:
        return [str(rng.choice(["living_room", "bedroom", "office", "kitchen"]))]
    types = ["living_room"]
    pool = ["bedroom", "kitchen", "bathroom", "office", "hallway"]
    weights = np.array([3.0, 2.5, 2.5, 1.5, 1.0])
    while len(types) < num_rooms:
        idx = int(rng.choice(len(pool), p=weights / weights.sum()))
        types.append(pool[idx])
        # Bedrooms and bathrooms may repeat once; the others are unique.
        limit = 2 if pool[idx] in ("bedroom", "bathroom") else 1
        if types.count(pool[idx]) >= limit:
            weights[idx] = 0.0
    order = rng.permutation(num_rooms)
    return [types[i] for i in order]


def layout_rooms(
    num_rooms: int, room_types: list[str], rng: np.random.Generator
) -> tuple[list[Room], list[Door]]:
    """Rectangular rooms in one or two rows, and doors making every room reachable."""
    if not 1 <= num_rooms <= 6:
        raise ValueError(f"num_rooms must be in [1, 6], got {num_rooms}")
    if len(room_types) != num_rooms:
        raise ValueError(f"room_types must have {num_rooms} entries, got {len(room_types)}")
    splits = _ROW_SPLITS[num_rooms]
    split = splits[int(rng.integers(len(splits)))]
    t = WALL_THICKNESS
    depths = [_q(rng.uniform(3.0, 5.0)) for _ in split]
    widths: list[list[float]] = []
    types = iter(room_types)
    for row_count in split:
        widths.append([_q(rng.uniform(*_width_range(next(types)))) for _ in range(row_count)])
    offsets = [0.0]
    if len(split) == 2:
        offset = _q(rng.uniform(-1.0, 1.0))
        if _best_overlap(widths, offset, t) < 2 * DOOR_MARGIN + 1.2:
            offset = 0.0
        offsets.append(offset)
    rooms: list[Room] = []
    rows: list[list[int]] = []
    y0 = 0.0
    for depth, row_widths, x0 in zip(depths, widths, offsets):
        row = []
        for width in row_widths:
            room_type = room_types[len(rooms)]
            rooms.append(Room(len(rooms), room_type, x0, y0, _q(x0 + width), _q(y0 + depth)))
            row.append(len(rooms) - 1)
            x0 = _q(x0 + width + t)
        rows.append(row)
        y0 = _q(y0 + depth + t)

    doors: list[Door] = []
    for row in rows:
        for a, b in zip(row[:-1], row[1:]):
            ra, rb = rooms[a], rooms[b]
            span = (max(ra.y0, rb.y0), min(ra.y1, rb.y1))
            doors.append(_door(a, b, ra.x1 + t / 2, span, "y", rng))
    if len(rows) == 2:
        pairs = []
        for a in rows[0]:
            for b in rows[1]:
                lo, hi = max(rooms[a].x0, rooms[b].x0), min(rooms[a].x1, rooms[b].x1)
                pairs.append((hi - lo, a, b, (lo, hi)))
        pairs.sort(key=lambda p: (-p[0], p[1], p[2]))
        chosen = [pairs[0]]
        for pair in pairs[1:]:
            if pair[0] >= 2.0 and rng.random() < 0.35:
                chosen.append(pair)
        for _, a, b, span in chosen:
            doors.append(_door(a, b, rooms[a].y1 + t / 2, span, "x", rng))
    return rooms, doors


def _width_range(room_type: str) -> tuple[float, float]:
    return (2.2, 3.0) if room_type == "hallway" else (3.0, 5.0)


def _best_overlap(widths: list[list[float]], offset: float, t: float) -> float:
    """Largest x overlap between a room of the south row and one of the north row."""

    def spans(row: list[float], x0: float) -> list[tuple[float, float]]:
        out = []
        for w in row:
            out.append((x0, x0 + w))
            x0 += w + t
        return out

    return max(
        min(a[1], b[1]) - max(a[0], b[0])
        for a in spans(widths[0], 0.0)
        for b in spans(widths[1], offset)
    )


def _door(
    a: int, b: int, line: float, span: tuple[float, float], axis: str, rng: np.random.Generator
) -> Door:
    """Door on the wall line ``line`` (x for axis 'y', y for axis 'x') within ``span``."""
    width = _q(rng.uniform(0.9, 1.1))
    lo, hi = span[0] + DOOR_MARGIN + width / 2, span[1] - DOOR_MARGIN - width / 2
    if hi < lo:
        raise ValueError(f"span {span} too short for a door of width {width}")
    centre = _q(rng.uniform(lo, hi)) if hi - lo > 0.05 else (lo + hi) / 2
    if axis == "y":
        return Door(a, b, round(line, 4), centre, width, "y")
    return Door(a, b, centre, round(line, 4), width, "x")


def _subtract(intervals: list[tuple[float, float]], cut: tuple[float, float]):
    out = []
    for lo, hi in intervals:
        if cut[1] <= lo or cut[0] >= hi:
            out.append((lo, hi))
            continue
        if cut[0] > lo:
            out.append((lo, cut[0]))
        if cut[1] < hi:
            out.append((cut[1], hi))
    return out


def _exterior_parts(room: Room, side: str, rooms: list[Room], t: float):
    """Sub-intervals of a room side (extended by t at both ends) with no room beyond it."""
    if side in ("s", "n"):
        parts = [(room.x0 - t, room.x1 + t)]
        for other in rooms:
            facing = other.y1 if side == "s" else other.y0
            target = room.y0 - t if side == "s" else room.y1 + t
            if other.index != room.index and abs(facing - target) < 0.02:
                parts = _subtract(parts, (other.x0, other.x1))
    else:
        parts = [(room.y0 - t, room.y1 + t)]
        for other in rooms:
            facing = other.x1 if side == "w" else other.x0
            target = room.x0 - t if side == "w" else room.x1 + t
            if other.index != room.index and abs(facing - target) < 0.02:
                parts = _subtract(parts, (other.y0, other.y1))
    return [p for p in parts if p[1] - p[0] > _TOL]


def wall_boxes(
    rooms: list[Room],
    doors: list[Door],
    thickness: float = WALL_THICKNESS,
    height: float = WALL_HEIGHT,
) -> list[WallBox]:
    """Wall boxes of a house: each room paints its own half of a wall; doors cut openings.

    Each room side gets an inner slab (half the thickness, coloured by that room); the parts
    of a side with no room beyond also get an outer slab, so every wall is ``thickness``
    thick. Doors remove their opening from every slab their line crosses and add a lintel
    above the opening (which does not block the robot).
    """
    t, h = thickness, height
    slabs: list[tuple[str, str, float, float, float, float, int]] = []
    for room in rooms:
        i = room.index
        # (side, along-axis, inner slab rect, outer slab offsets)
        slabs.append((f"{i}_s", "x", room.x0 - t / 2, room.y0 - t / 2, room.x1 + t / 2, room.y0, i))
        slabs.append((f"{i}_n", "x", room.x0 - t / 2, room.y1, room.x1 + t / 2, room.y1 + t / 2, i))
        slabs.append((f"{i}_w", "y", room.x0 - t / 2, room.y0 - t / 2, room.x0, room.y1 + t / 2, i))
        slabs.append((f"{i}_e", "y", room.x1, room.y0 - t / 2, room.x1 + t / 2, room.y1 + t / 2, i))
        for side in ("s", "n", "w", "e"):
            for k, (lo, hi) in enumerate(_exterior_parts(room, side, rooms, t)):
                if side == "s":
                    rect = (lo, room.y0 - t, hi, room.y0 - t / 2)
                elif side == "n":
                    rect = (lo, room.y1 + t / 2, hi, room.y1 + t)
                elif side == "w":
                    rect = (room.x0 - t, lo, room.x0 - t / 2, hi)
                else:
                    rect = (room.x1 + t / 2, lo, room.x1 + t, hi)
                axis = "x" if side in ("s", "n") else "y"
                slabs.append((f"ext{i}_{side}{k}", axis, *rect, -1))

    boxes: list[WallBox] = []
    for name, axis, x0, y0, x1, y1, room_index in slabs:
        pieces = [(x0, x1)] if axis == "x" else [(y0, y1)]
        for door in doors:
            if door.axis != axis:
                continue
            across = (y0, y1) if axis == "x" else (x0, x1)
            line = door.y if axis == "x" else door.x
            if across[0] - _TOL <= line <= across[1] + _TOL:
                centre = door.x if axis == "x" else door.y
                pieces = _subtract(pieces, (centre - door.width / 2, centre + door.width / 2))
        for k, (lo, hi) in enumerate(p for p in pieces if p[1] - p[0] > _TOL):
            rect = (lo, y0, hi, y1) if axis == "x" else (x0, lo, x1, hi)
            boxes.append(WallBox(f"wall_{name}_{k}", *rect, 0.0, h, room_index))
    for k, door in enumerate(doors):
        half_w, half_t = door.width / 2, t / 2
        if door.axis == "x":
            rect = (door.x - half_w, door.y - half_t, door.x + half_w, door.y + half_t)
        else:
            rect = (door.x - half_t, door.y - half_w, door.x + half_t, door.y + half_w)
        boxes.append(WallBox(f"wall_door{k}_lintel", *rect, DOOR_HEIGHT, h, -1))
    return boxes


def door_clear_zones(room: Room, doors: list[Door], depth: float = 1.0, side_margin: float = 0.2):
    """Rectangles (x0, y0, x1, y1) inside ``room`` in front of each of its doors, kept free."""
    zones = []
    for door in doors:
        if room.index not in (door.room_a, door.room_b):
            continue
        half = door.width / 2 + side_margin
        if door.axis == "x":
            if abs(door.y - room.y0) < abs(door.y - room.y1):
                zones.append((door.x - half, room.y0, door.x + half, room.y0 + depth))
            else:
                zones.append((door.x - half, room.y1 - depth, door.x + half, room.y1))
        else:
            if abs(door.x - room.x0) < abs(door.x - room.x1):
                zones.append((room.x0, door.y - half, room.x0 + depth, door.y + half))
            else:
                zones.append((room.x1 - depth, door.y - half, room.x1, door.y + half))
    return zones
