"""Procedural houses: floorplan + furniture -> :class:`House` (occupancy grid) and MJCF.

``generate_house(seed)`` is fully determined by its arguments. The occupancy grid follows the
``GridSpec`` convention (a cell is occupied when its centre lies inside a wall box or an object
footprint; everything outside the house is occupied too). After placement, the free space of
a robot of radius ``ROBOT_RADIUS`` is checked to be one connected region from which every
object can be touched; pieces that close off a pocket or cannot be reached are dropped.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import ndimage

from vla_gr.envs.floorplan import (
    WALL_HEIGHT,
    WALL_THICKNESS,
    WallBox,
    layout_rooms,
    sample_room_types,
    wall_boxes,
)
from vla_gr.envs.furniture import collision_geom, object_geoms
from vla_gr.envs.geodesic import ROBOT_RADIUS, traversable_cells
from vla_gr.envs.house_style import Texture, house_look
from vla_gr.envs.placement import Placed, place_furniture
from vla_gr.envs.scene import Door, House, ObjectInstance, Room
from vla_gr.geometry import GridSpec, disk_kernel

logger = logging.getLogger(__name__)

SPLITS: dict[str, int] = {"train": 0, "val": 1_000_000, "test": 2_000_000}
SPLIT_SIZE = 1_000_000
GRID_MARGIN = 0.5

#: Wall paint and floor finish per room type (RGBA); a little jitter per house.
_WALL_PAINT = {
    "kitchen": (0.93, 0.90, 0.78),
    "living_room": (0.88, 0.84, 0.76),
    "bedroom": (0.78, 0.84, 0.92),
    "bathroom": (0.80, 0.92, 0.90),
    "office": (0.86, 0.88, 0.80),
    "hallway": (0.85, 0.85, 0.85),
}
_FLOOR_FINISH = {
    "kitchen": (0.62, 0.62, 0.60),
    "living_room": (0.55, 0.40, 0.27),
    "bedroom": (0.64, 0.50, 0.36),
    "bathroom": (0.72, 0.74, 0.76),
    "office": (0.40, 0.36, 0.34),
    "hallway": (0.50, 0.45, 0.40),
}


def split_seed(split: str, index: int) -> int:
    """Scene seed of episode/scene ``index`` of ``split``; splits use disjoint seed ranges."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {sorted(SPLITS)}, got {split!r}")
    if not 0 <= int(index) < SPLIT_SIZE:
        raise ValueError(f"index must be in [0, {SPLIT_SIZE}), got {index}")
    return SPLITS[split] + int(index)


# --------------------------------------------------------------------------- rasterisation


def _grid_for(rooms: list[Room], cell_size: float, margin: float) -> GridSpec:
    t = WALL_THICKNESS
    x0 = min(r.x0 for r in rooms) - t - margin
    y0 = min(r.y0 for r in rooms) - t - margin
    x1 = max(r.x1 for r in rooms) + t + margin
    y1 = max(r.y1 for r in rooms) + t + margin
    ox, oy = np.floor(x0 / cell_size) * cell_size, np.floor(y0 / cell_size) * cell_size
    width = int(np.ceil((x1 - ox) / cell_size))
    height = int(np.ceil((y1 - oy) / cell_size))
    return GridSpec(round(ox, 6), round(oy, 6), cell_size, height, width)


def _cell_range(lo: float, hi: float, origin: float, cell: float, n: int) -> slice:
    """Cells whose centre lies in [lo, hi] along one axis."""
    a = int(np.ceil((lo - origin) / cell - 0.5 - 1e-9))
    b = int(np.floor((hi - origin) / cell - 0.5 + 1e-9))
    return slice(max(a, 0), max(min(b + 1, n), 0))


def rasterize_box(mask: np.ndarray, grid: GridSpec, x0, y0, x1, y1, value=True) -> None:
    """Set ``mask`` (H, W) to ``value`` on cells whose centre lies in the box (in place)."""
    rows = _cell_range(y0, y1, grid.origin_y, grid.cell_size, grid.height)
    cols = _cell_range(x0, x1, grid.origin_x, grid.cell_size, grid.width)
    mask[rows, cols] = value


def footprint_cells(obj: ObjectInstance, grid: GridSpec) -> tuple[slice, slice, np.ndarray]:
    """(rows, cols, inside) where ``inside`` (h, w) marks window cells inside the footprint."""
    corners = obj.footprint()  # (4, 2)
    rows = _cell_range(
        corners[:, 1].min(), corners[:, 1].max(), grid.origin_y, grid.cell_size, grid.height
    )
    cols = _cell_range(
        corners[:, 0].min(), corners[:, 0].max(), grid.origin_x, grid.cell_size, grid.width
    )
    xs = grid.origin_x + (np.arange(cols.start, cols.stop) + 0.5) * grid.cell_size  # (w,)
    ys = grid.origin_y + (np.arange(rows.start, rows.stop) + 0.5) * grid.cell_size  # (h,)
    dx, dy = xs[None, :] - obj.x, ys[:, None] - obj.y  # (1, w), (h, 1)
    c, s = np.cos(obj.yaw), np.sin(obj.yaw)
    lx, ly = c * dx + s * dy, -s * dx + c * dy  # (h, w) each, in the object's frame
    hx, hy = obj.half_extents
    inside = (np.abs(lx) <= hx + 1e-9) & (np.abs(ly) <= hy + 1e-9)  # (h, w)
    return rows, cols, inside


def structure_occupancy(rooms: list[Room], doors: list[Door], grid: GridSpec) -> np.ndarray:
    """(H, W) bool: walls (robot height) plus everything outside the house."""
    outside = np.ones(grid.shape, bool)
    t = WALL_THICKNESS
    for room in rooms:
        rasterize_box(outside, grid, room.x0 - t, room.y0 - t, room.x1 + t, room.y1 + t, False)
    occ = outside
    for box in wall_boxes(rooms, doors):
        if box.blocks_robot:
            rasterize_box(occ, grid, box.x0, box.y0, box.x1, box.y1)
    return occ


def object_id_grid(objects: list[ObjectInstance], grid: GridSpec) -> np.ndarray:
    """(H, W) int32 instance id covering each cell (0 where no footprint)."""
    ids = np.zeros(grid.shape, np.int32)
    for obj in objects:
        rows, cols, inside = footprint_cells(obj, grid)
        window = ids[rows, cols]
        window[inside] = obj.instance_id
    return ids


def build_house(
    seed: int,
    rooms: list[Room],
    doors: list[Door],
    objects: list[ObjectInstance],
    cell_size: float = 0.05,
    margin: float = GRID_MARGIN,
    meta: dict | None = None,
) -> House:
    """Rasterise rooms, doors and objects into a :class:`House` (also for hand-built scenes)."""
    if not 0 < cell_size <= 0.05:
        raise ValueError(f"cell_size must be in (0, 0.05] m, got {cell_size}")
    if not rooms:
        raise ValueError("rooms must not be empty")
    grid = _grid_for(rooms, cell_size, margin)
    ids = object_id_grid(objects, grid)
    occ = structure_occupancy(rooms, doors, grid) | (ids > 0)
    return House(
        seed, list(rooms), list(doors), list(objects), grid, occ, ids, WALL_HEIGHT, meta or {}
    )


# --------------------------------------------------------------------------- verification


def _touch_kernel(grid: GridSpec, robot_radius: float) -> np.ndarray:
    return disk_kernel(robot_radius + 1.5 * grid.cell_size, grid.cell_size)


def unreachable_problems(
    house: House, robot_radius: float = ROBOT_RADIUS
) -> tuple[list[np.ndarray], list[int]]:
    """(pockets, unreachable ids): traversable components besides the largest, and objects
    whose footprint no cell of the largest component touches (centre within radius + 1.5 cells).
    """
    free = traversable_cells(house, robot_radius)  # (H, W)
    labels, count = ndimage.label(free, structure=np.ones((3, 3), int))
    if count == 0:
        return [], [o.instance_id for o in house.objects]
    sizes = np.bincount(labels.ravel())[1:]
    main_label = int(np.argmax(sizes)) + 1
    pockets = [labels == k for k in range(1, count + 1) if k != main_label]
    main = labels == main_label  # (H, W)
    # Distance (m) from every cell centre to the nearest main-region cell centre.
    to_main = ndimage.distance_transform_edt(~main) * house.grid.cell_size  # (H, W)
    reach = robot_radius + 1.5 * house.grid.cell_size
    unreachable = []
    for obj in house.objects:
        rows, cols, inside = footprint_cells(obj, house.grid)
        if not inside.any() or to_main[rows, cols][inside].min() > reach + 1e-9:
            unreachable.append(obj.instance_id)
    return pockets, unreachable


def _prune(house_args: dict, placed: list[Placed], robot_radius: float) -> list[Placed]:
    """Drop pieces until free space is connected and every piece is reachable."""
    for _ in range(len(placed) + 1):
        objects = [p.obj for p in placed]
        house = build_house(objects=objects, **house_args)
        pockets, unreachable = unreachable_problems(house, robot_radius)
        if not pockets and not unreachable:
            return placed
        culprits = set(unreachable)
        kernel = _touch_kernel(house.grid, robot_radius)
        for pocket in pockets:
            near = ndimage.binary_dilation(pocket, structure=kernel)
            culprits.update(int(i) for i in np.unique(house.object_ids[near]) if i > 0)
        if not culprits:
            logger.warning("house %s: free space split by walls alone", house.seed)
            return placed
        # Drop the least important culprit: optional before essential, later before earlier.
        order = {p.obj.instance_id: (p.essential, -k) for k, p in enumerate(placed)}
        victim = min(culprits, key=lambda i: order[i])
        placed = [p for p in placed if p.obj.instance_id != victim]
    return placed


# --------------------------------------------------------------------------- generation


def generate_house(
    seed: int, num_rooms: int | None = None, clutter: float = 1.0, cell_size: float = 0.05
) -> House:
    """A procedural house fully determined by the arguments.

    Args:
        seed: scene seed (see :func:`split_seed`).
        num_rooms: 1..6 rooms, or None to draw 2..5 from the seed.
        clutter: >= 0, scales how many optional pieces each room gets.
        cell_size: occupancy cell size in metres, in (0, 0.05].

    Returns:
        A :class:`House`; ``occupancy`` (H, W) bool and ``object_ids`` (H, W) int32.
    """
    if num_rooms is not None and not 1 <= int(num_rooms) <= 6:
        raise ValueError(f"num_rooms must be in [1, 6] or None, got {num_rooms}")
    if not 0.0 <= clutter <= 4.0:
        raise ValueError(f"clutter must be in [0, 4], got {clutter}")
    if not 0 < cell_size <= 0.05:
        raise ValueError(f"cell_size must be in (0, 0.05] m, got {cell_size}")
    rng = np.random.default_rng(int(seed))
    n = int(rng.integers(2, 6)) if num_rooms is None else int(num_rooms)
    rooms, doors = layout_rooms(n, sample_room_types(n, rng), rng)
    placed = place_furniture(rooms, doors, clutter, rng)
    meta = {
        "num_rooms": n,
        "clutter": float(clutter),
        "wall_rgba": [_jitter(_WALL_PAINT[r.room_type], rng) for r in rooms],
        "floor_rgba": [_jitter(_FLOOR_FINISH[r.room_type], rng) for r in rooms],
    }
    args = dict(seed=int(seed), rooms=rooms, doors=doors, cell_size=cell_size, meta=meta)
    placed = _prune(args, placed, ROBOT_RADIUS)
    objects = [_renumber(p.obj, k + 1) for k, p in enumerate(placed)]
    return build_house(objects=objects, **args)


def _jitter(rgb: tuple[float, float, float], rng: np.random.Generator) -> list[float]:
    return [round(float(np.clip(c + rng.uniform(-0.05, 0.05), 0.0, 1.0)), 3) for c in rgb] + [1.0]


def _renumber(obj: ObjectInstance, instance_id: int) -> ObjectInstance:
    return ObjectInstance(
        instance_id,
        obj.category,
        obj.color,
        obj.room_index,
        obj.x,
        obj.y,
        obj.yaw,
        obj.half_extents,
        obj.height,
    )


# --------------------------------------------------------------------------- MJCF


def _f(*values: float) -> str:
    """Fixed-precision numbers for MJCF (identical strings for identical houses)."""
    return " ".join(f"{v:.5f}".rstrip("0").rstrip(".") or "0" for v in values)


def _wall_xml(box: WallBox, material: str) -> str:
    half = ((box.x1 - box.x0) / 2, (box.y1 - box.y0) / 2, (box.z1 - box.z0) / 2)
    pos = ((box.x0 + box.x1) / 2, (box.y0 + box.y1) / 2, (box.z0 + box.z1) / 2)
    cls = "static" if box.blocks_robot else "visual"
    return (
        f'    <geom name="{box.name}" class="{cls}" type="box" size="{_f(*half)}" '
        f'pos="{_f(*pos)}" material="{material}"/>'
    )


def _texture_xml(tex: Texture) -> str:
    marks = (
        f' mark="{tex.mark}" markrgb="{_f(*tex.markrgb)}" random="{_f(tex.random)}"'
        if tex.mark != "none"
        else ""
    )
    return (
        f'    <texture name="{tex.name}" type="2d" builtin="{tex.builtin}" rgb1="{_f(*tex.rgb1)}" '
        f'rgb2="{_f(*tex.rgb2)}" width="{tex.size}" height="{tex.size}"{marks}/>'
    )


def _material_xml(name: str, rgba, specular: float | None, tex: Texture | None) -> str:
    spec = f' specular="{_f(specular)}"' if specular is not None else ""
    texture = (
        f' texture="{tex.name}" texrepeat="{_f(tex.repeat, tex.repeat)}" texuniform="true"'
        if tex is not None
        else ""
    )
    return f'    <material name="{name}" rgba="{_f(*rgba)}"{spec}{texture}/>'


def house_to_mjcf(
    house: House, robot_xml: str = "", robot_assets: str = "", house_style: str = "default"
) -> str:
    """Complete MJCF model of ``house``; ``robot_xml`` (a <body>) goes into <worldbody>.

    Geom naming: furniture ``obj{id}_<part>`` inside body ``obj{id}``; walls ``wall_...``;
    floor ``floor``. Static collision geoms use contype=1 conaffinity=0, so they collide with
    a robot of contype=1 conaffinity=1 but never with each other; visual parts do not collide.
    Each piece has an invisible box ``obj{id}_collision`` (group 3) filling its footprint up to
    robot height, matching the occupancy grid. ``house_style`` (:mod:`.house_style`) sets the
    walls', floors', light's and unnamed furniture parts' look; ``default`` is the training world.
    """
    look = house_look(house, house_style)
    wall_rgba, floor_rgba = look.wall_rgba, look.floor_rgba
    t = WALL_THICKNESS
    x0 = min(r.x0 for r in house.rooms) - t
    y0 = min(r.y0 for r in house.rooms) - t
    x1 = max(r.x1 for r in house.rooms) + t
    y1 = max(r.y1 for r in house.rooms) + t
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    extent = max(x1 - x0, y1 - y0)

    lines = [
        f'<mujoco model="house_{house.seed}">',
        '  <compiler angle="radian"/>',
        '  <option timestep="0.02"/>',
        f'  <statistic center="{_f(cx, cy, 1.0)}" extent="{_f(extent)}"/>',
        "  <visual>",
        '    <quality shadowsize="0" offsamples="0" numslices="8" numstacks="4"/>',
        f'    <headlight ambient="{_f(*[look.headlight_ambient] * 3)}" '
        f'diffuse="{_f(*[look.headlight_diffuse] * 3)}" specular="0 0 0"/>',
        # map znear/zfar are relative to the extent: near 5 cm, far 40 m in absolute terms.
        f'    <map znear="{_f(0.05 / extent)}" zfar="{_f(40.0 / extent)}"/>',
        "  </visual>",
        "  <default>",
        '    <default class="static"><geom contype="1" conaffinity="0" group="0"/></default>',
        '    <default class="visual"><geom contype="0" conaffinity="0" group="0"/></default>',
        '    <default class="collider">',
        '      <geom contype="1" conaffinity="0" group="3" rgba="0.5 0.5 0.5 0"/>',
        "    </default>",
        "  </default>",
        "  <asset>",
    ]
    lines += [_texture_xml(x) for x in (look.wall_texture, look.floor_texture) if x is not None]
    wall_tex, floor_tex = look.wall_texture, look.floor_texture
    for i, (w, fl) in enumerate(zip(wall_rgba, floor_rgba)):
        lines.append(_material_xml(f"wall_mat{i}", w, look.wall_specular, wall_tex))
        lines.append(_material_xml(f"floor_mat{i}", fl, look.floor_specular, floor_tex))
    lines.append(_material_xml("wall_ext", look.wall_ext_rgba, look.wall_specular, wall_tex))
    lines.append(_material_xml("floor_base", look.floor_base_rgba, None, None))
    if robot_assets:
        lines.append(robot_assets)
    lines += [
        "  </asset>",
        "  <worldbody>",
        '    <light name="sun" directional="true" castshadow="false" pos="0 0 5" '
        f'dir="{_f(*look.sun_dir)}" diffuse="{_f(*[look.sun_diffuse] * 3)}" specular="0 0 0"/>',
        f'    <geom name="floor" class="static" type="box" '
        f'size="{_f((x1 - x0) / 2, (y1 - y0) / 2, 0.05)}" '
        f'pos="{_f(cx, cy, -0.05)}" material="floor_base"/>',
    ]
    for room, _ in zip(house.rooms, floor_rgba):
        half = ((room.x1 - room.x0) / 2, (room.y1 - room.y0) / 2, 0.001)
        pos = ((room.x0 + room.x1) / 2, (room.y0 + room.y1) / 2, 0.001)
        lines.append(
            f'    <geom name="floor_room{room.index}" class="visual" type="box" '
            f'size="{_f(*half)}" pos="{_f(*pos)}" material="floor_mat{room.index}"/>'
        )
    for box in wall_boxes(house.rooms, house.doors):
        lines.append(_wall_xml(box, f"wall_mat{box.room}" if box.room >= 0 else "wall_ext"))
    for obj in house.objects:
        lines.append(
            f'    <body name="{obj.body_name}" pos="{_f(obj.x, obj.y, 0.0)}" '
            f'euler="{_f(0.0, 0.0, obj.yaw)}">'
        )
        col = collision_geom(obj)
        lines.append(
            f'      <geom name="{obj.body_name}_{col.suffix}" class="collider" type="box" '
            f'size="{_f(*col.size)}" pos="{_f(*col.pos)}"/>'
        )
        for g in object_geoms(obj):
            rgba = look.finish(g.finish, g.rgba)  # a named colour is never restyled
            lines.append(
                f'      <geom name="{obj.body_name}_{g.suffix}" class="visual" type="{g.kind}" '
                f'size="{_f(*g.size)}" pos="{_f(*g.pos)}" rgba="{_f(*rgba)}"/>'
            )
        lines.append("    </body>")
    if robot_xml:
        lines.append(robot_xml)
    lines += ["  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)
