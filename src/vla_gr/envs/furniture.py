"""Furniture built from MuJoCo primitives: sizes per category and the geoms of each piece.

Every piece lives in its own local frame: the footprint is ``[-hx, hx] x [-hy, hy]``, the
back of the piece is at ``-y`` (against a wall) and its front faces ``+y``; ``z = 0`` is the
floor. The geoms are a pure function of an :class:`ObjectInstance`, so the MJCF of a house
is reproducible from its object list alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vla_gr.envs.scene import COLORS, ObjectInstance

#: Height (m) of the invisible collision box that matches the footprint (robot height).
COLLISION_HEIGHT = 0.4

#: Colours each category may take (names from ``scene.COLORS``).
PALETTES: dict[str, tuple[str, ...]] = {
    "chair": tuple(COLORS),
    "sofa": tuple(COLORS),
    "bed": tuple(COLORS),
    "toilet": ("white", "black", "blue", "yellow", "green", "red"),
    "tv_monitor": tuple(COLORS),
    "plant": ("green", "red", "yellow", "purple", "orange", "blue"),
    "table": tuple(COLORS),
    "cabinet": tuple(COLORS),
}

_WOOD = (0.45, 0.30, 0.18, 1.0)
_DARK = (0.10, 0.10, 0.11, 1.0)
_SCREEN = (0.02, 0.03, 0.05, 1.0)
_LINEN = (0.95, 0.95, 0.92, 1.0)
_POT = (0.30, 0.22, 0.18, 1.0)
_METAL = (0.60, 0.60, 0.62, 1.0)


@dataclass(frozen=True)
class Geom:
    """One primitive in an object's local frame (MuJoCo half sizes, metres)."""

    suffix: str
    kind: str  # "box" | "cylinder" | "sphere" | "ellipsoid"
    size: tuple[float, ...]
    pos: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    # a part that carries no named colour (``house_style.FINISHES``): a house style may
    # draw it in another material; None = the object's named colour (never restyled)
    finish: str | None = None


def color_rgba(name: str) -> tuple[float, float, float, float]:
    """Named colour -> RGBA tuple; raises ValueError for unknown names."""
    if name not in COLORS:
        raise ValueError(f"color must be one of {sorted(COLORS)}, got {name!r}")
    return (*COLORS[name], 1.0)


def shade(rgba: tuple[float, ...], factor: float) -> tuple[float, float, float, float]:
    """Darken (factor < 1) or lighten (factor > 1, towards white) an RGBA colour."""
    r, g, b = rgba[:3]
    if factor <= 1.0:
        return (r * factor, g * factor, b * factor, 1.0)
    t = min(factor - 1.0, 1.0)
    return (r + (1 - r) * t, g + (1 - g) * t, b + (1 - b) * t, 1.0)


def sample_dimensions(category: str, rng: np.random.Generator) -> tuple[float, float, float]:
    """Random footprint half extents (hx, hy) and height (m) for one piece of ``category``."""

    def u(lo: float, hi: float) -> float:
        return round(float(rng.uniform(lo, hi)), 3)

    if category == "chair":
        half = u(0.21, 0.25)
        return half, half, u(0.82, 0.95)
    if category == "sofa":
        return u(0.75, 1.05), u(0.38, 0.45), u(0.75, 0.85)
    if category == "bed":
        return u(0.65, 0.9), u(0.95, 1.05), u(0.9, 1.05)
    if category == "toilet":
        return u(0.19, 0.21), u(0.31, 0.35), u(0.72, 0.8)
    if category == "tv_monitor":
        return u(0.45, 0.7), u(0.2, 0.25), u(1.15, 1.35)
    if category == "plant":
        half = u(0.18, 0.28)
        return half, half, u(0.75, 1.3)
    if category == "table":
        return u(0.5, 0.8), u(0.4, 0.5), u(0.72, 0.78)
    if category == "cabinet":
        return u(0.25, 0.55), u(0.2, 0.28), u(0.6, 1.8)
    raise ValueError(f"category must be one of the known furniture categories, got {category!r}")


def _legs(hx: float, hy: float, top: float, inset: float, radius: float, rgba) -> list[Geom]:
    """Four cylindrical legs (finish ``legs``) from the floor to ``top`` at the corners."""
    legs = []
    for i, (sx, sy) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        pos = (sx * (hx - inset), sy * (hy - inset), top / 2)
        legs.append(Geom(f"leg{i}", "cylinder", (radius, top / 2), pos, rgba, "legs"))
    return legs


def _chair(hx, hy, h, c) -> list[Geom]:
    seat_z = 0.45
    back_half = (h - seat_z - 0.03) / 2
    return [
        Geom("seat", "box", (hx, hy, 0.03), (0.0, 0.0, seat_z), c),
        Geom("back", "box", (hx, 0.025, back_half), (0.0, -hy + 0.025, h - back_half), c),
        *_legs(hx, hy, seat_z - 0.03, 0.03, 0.02, shade(c, 0.45)),
    ]


def _sofa(hx, hy, h, c) -> list[Geom]:
    arm = 0.12
    return [
        Geom("base", "box", (hx, hy, 0.2), (0.0, 0.0, 0.2), shade(c, 0.8)),
        Geom("cushion", "box", (hx - arm, hy - 0.13, 0.06), (0.0, 0.11, 0.46), c),
        Geom("back", "box", (hx, 0.12, (h - 0.4) / 2), (0.0, -hy + 0.12, (h + 0.4) / 2), c),
        Geom("arm0", "box", (arm, hy, 0.14), (-hx + arm, 0.0, 0.54), shade(c, 0.9)),
        Geom("arm1", "box", (arm, hy, 0.14), (hx - arm, 0.0, 0.54), shade(c, 0.9)),
    ]


def _bed(hx, hy, h, c) -> list[Geom]:
    return [
        Geom("frame", "box", (hx, hy, 0.15), (0.0, 0.0, 0.15), shade(c, 0.6)),
        Geom("mattress", "box", (hx - 0.03, hy - 0.06, 0.1), (0.0, 0.03, 0.4), _LINEN, "linen"),
        Geom("blanket", "box", (hx - 0.02, hy * 0.6, 0.03), (0.0, hy * 0.38, 0.5), c),
        Geom("headboard", "box", (hx, 0.04, h / 2), (0.0, -hy + 0.04, h / 2), shade(c, 0.5)),
        Geom(
            "pillow", "ellipsoid", (hx * 0.6, 0.14, 0.06), (0.0, -hy + 0.3, 0.54), _LINEN, "linen"
        ),
    ]


def _toilet(hx, hy, h, c) -> list[Geom]:
    r = hx * 0.95
    bowl_y = hy - r
    tank_half = (h - 0.4) / 2
    return [
        Geom("pedestal", "box", (0.11, 0.14, 0.14), (0.0, bowl_y - 0.04, 0.14), c),
        Geom("bowl", "cylinder", (r, 0.07), (0.0, bowl_y, 0.33), c),
        Geom("seat", "cylinder", (r, 0.012), (0.0, bowl_y, 0.412), shade(c, 0.85)),
        Geom("tank", "box", (hx - 0.01, 0.09, tank_half), (0.0, -hy + 0.09, 0.4 + tank_half), c),
        Geom("riser", "box", (0.1, 0.1, 0.2), (0.0, -hy + 0.1, 0.2), c),
        Geom(
            "flush", "box", (0.03, 0.01, 0.01), (hx * 0.5, -hy + 0.185, h - 0.06), _METAL, "metal"
        ),
    ]


def _tv_monitor(hx, hy, h, c) -> list[Geom]:
    stand_half = 0.25
    screen_half = min((h - 2 * stand_half - 0.1) / 2, hx * 0.6)
    screen_z = h - screen_half
    return [
        Geom("stand", "box", (hx, hy, stand_half), (0.0, 0.0, stand_half), c),
        Geom("neck", "box", (0.04, 0.03, 0.06), (0.0, -0.05, 2 * stand_half + 0.06), _DARK, "dark"),
        Geom("frame", "box", (hx * 0.92, 0.025, screen_half), (0.0, -0.05, screen_z), c),
        Geom(
            "screen",
            "box",
            (hx * 0.86, 0.004, screen_half - 0.04),
            (0.0, -0.021, screen_z),
            _SCREEN,
            "screen",
        ),
    ]


def _plant(hx, hy, h, c) -> list[Geom]:
    radius = min(hx, hy)
    pot_r, pot_half = radius * 0.7, 0.15
    crown_r, leaf_r, top_r = radius * 0.75, radius * 0.5, radius * 0.55
    crown_z = max(h - 2 * top_r - crown_r * 0.3, 2 * pot_half + crown_r)
    geoms = [
        Geom("pot", "cylinder", (pot_r, pot_half), (0.0, 0.0, pot_half), _POT, "pot"),
        Geom("soil", "cylinder", (pot_r * 0.9, 0.01), (0.0, 0.0, 2 * pot_half), _DARK, "dark"),
        Geom(
            "stem",
            "cylinder",
            (0.02, (crown_z - 0.3) / 2),
            (0.0, 0.0, (crown_z + 0.3) / 2),
            _WOOD,
            "wood",
        ),
        Geom("foliage", "sphere", (crown_r,), (0.0, 0.0, crown_z), c),
        Geom("top", "sphere", (top_r,), (0.0, 0.0, h - top_r), shade(c, 1.15)),
    ]
    for k in range(3):  # leaf clusters around the crown, inside the footprint
        angle = 2 * np.pi * k / 3 + 0.5
        pos = (0.45 * radius * np.cos(angle), 0.45 * radius * np.sin(angle), crown_z - 0.08)
        geoms.append(Geom(f"leaves{k}", "sphere", (leaf_r,), pos, shade(c, 0.8)))
    return geoms


def _table(hx, hy, h, c) -> list[Geom]:
    return [
        Geom("top", "box", (hx, hy, 0.025), (0.0, 0.0, h - 0.025), c),
        *_legs(hx, hy, h - 0.05, 0.05, 0.025, shade(c, 0.5)),
    ]


def _cabinet(hx, hy, h, c) -> list[Geom]:
    geoms = [
        Geom("body", "box", (hx, hy - 0.02, h / 2), (0.0, -0.02, h / 2), c),
        Geom("seam", "box", (0.004, 0.003, h / 2 - 0.04), (0.0, hy - 0.038, h / 2), shade(c, 0.4)),
    ]
    handle_z = min(h * 0.55, 1.0)
    for i, sx in enumerate((-1.0, 1.0)):
        pos = (sx * min(0.06, hx * 0.3), hy - 0.01, handle_z)
        geoms.append(Geom(f"handle{i}", "box", (0.012, 0.01, 0.07), pos, _METAL, "metal"))
    return geoms


_BUILDERS = {
    "chair": _chair,
    "sofa": _sofa,
    "bed": _bed,
    "toilet": _toilet,
    "tv_monitor": _tv_monitor,
    "plant": _plant,
    "table": _table,
    "cabinet": _cabinet,
}


def object_geoms(obj: ObjectInstance) -> list[Geom]:
    """Visual geoms (local frame) of ``obj``; all lie inside its footprint."""
    if obj.category not in _BUILDERS:
        raise ValueError(f"obj.category must be one of {sorted(_BUILDERS)}, got {obj.category!r}")
    hx, hy = obj.half_extents
    return _BUILDERS[obj.category](hx, hy, obj.height, color_rgba(obj.color))


def collision_geom(obj: ObjectInstance) -> Geom:
    """Invisible box filling the footprint from the floor to robot height."""
    hx, hy = obj.half_extents
    half_z = COLLISION_HEIGHT / 2
    return Geom("collision", "box", (hx, hy, half_z), (0.0, 0.0, half_z), (0.5, 0.5, 0.5, 0.0))
