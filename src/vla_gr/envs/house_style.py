"""House styles: how a house looks (walls, floors, lighting, unnamed furniture finishes).

``house_style`` (``env.house_style``) picks one; :func:`house_look` resolves it for one house
and :func:`~vla_gr.envs.house.house_to_mjcf` writes it. ``default`` is the world every agent
was trained and measured in: its MJCF is byte-identical to the one written before styles
existed. ``loft`` is held out (no training stage uses it unless told to): saturated speckled
walls, dark checkered floors, dimmer light from another side, and other materials for the
furniture parts that carry no named colour (wood, legs, pots, linen, metal, screens, dark
parts). An object's named colour is never restyled: it is the semantic label instructions
use ("the red chair" stays red), so a style shifts appearance, not meaning.

A style is deterministic per house: its draws come from ``(house.seed, style)`` alone, never
from the house generator's stream, so the house, its episodes and the default look are
unchanged. Geometry, collisions, depth and segmentation do not depend on the style.
"""

from __future__ import annotations

import colorsys
import zlib
from dataclasses import dataclass, field

import numpy as np

from vla_gr.envs.scene import House

__all__ = ["HOUSE_STYLES", "FINISHES", "HouseLook", "Texture", "check_house_style", "house_look"]

#: Styles by name: ``default`` (the training world) and the held-out ``loft``.
HOUSE_STYLES: tuple[str, ...] = ("default", "loft")

RGBA = tuple[float, float, float, float]

#: Furniture finishes (``furniture.Geom.finish``): the parts that carry no named colour.
FINISHES: tuple[str, ...] = ("wood", "dark", "screen", "linen", "pot", "metal", "legs")


def check_house_style(house_style: str) -> str:
    """``house_style`` itself; ValueError naming the valid styles otherwise."""
    if house_style not in HOUSE_STYLES:
        raise ValueError(
            f"house_style={house_style!r} is not a house style; choose one of "
            f"{', '.join(HOUSE_STYLES)}"
        )
    return house_style


@dataclass(frozen=True)
class Texture:
    """A MuJoCo builtin 2-D texture; a material's ``rgba`` tints it (white = as drawn)."""

    name: str
    builtin: str  # "checker" | "flat" (with random marks)
    rgb1: tuple[float, float, float]
    rgb2: tuple[float, float, float]
    size: int  # texels per side
    repeat: float  # repetitions per metre (``texuniform``)
    mark: str = "none"  # "random": speckles of ``markrgb`` over a share ``random`` of texels
    markrgb: tuple[float, float, float] = (0.0, 0.0, 0.0)
    random: float = 0.0


@dataclass(frozen=True)
class HouseLook:
    """Everything the MJCF of one house takes from its style (RGBA in [0, 1])."""

    wall_rgba: list[list[float]]  # per room
    floor_rgba: list[list[float]]  # per room
    wall_ext_rgba: RGBA = (0.8, 0.8, 0.78, 1.0)  # walls of no room (outside faces)
    floor_base_rgba: RGBA = (0.35, 0.35, 0.35, 1.0)  # the slab under the rooms
    wall_specular: float = 0.1
    floor_specular: float = 0.2
    wall_texture: Texture | None = None
    floor_texture: Texture | None = None
    headlight_ambient: float = 0.45
    headlight_diffuse: float = 0.35
    sun_diffuse: float = 0.5
    sun_dir: tuple[float, float, float] = (0.3, 0.2, -1.0)
    finishes: dict[str, RGBA] = field(default_factory=dict)  # finish -> RGBA that replaces it

    def finish(self, name: str | None, rgba: RGBA) -> RGBA:
        """The RGBA a furniture part of ``finish`` ``name`` is drawn in (``rgba``: its own)."""
        return self.finishes.get(name, rgba) if name is not None else rgba


def house_look(house: House, house_style: str = "default") -> HouseLook:
    """The look of ``house`` in ``house_style`` (see the module docstring)."""
    check_house_style(house_style)
    n = len(house.rooms)
    walls = house.meta.get("wall_rgba") or [[0.85, 0.85, 0.82, 1.0]] * n
    floors = house.meta.get("floor_rgba") or [[0.55, 0.45, 0.35, 1.0]] * n
    if house_style == "default":
        return HouseLook(wall_rgba=list(walls), floor_rgba=list(floors))
    return _loft(house, np.random.default_rng([int(house.seed), zlib.crc32(b"loft")]))


def _hsv(h: float, s: float, v: float) -> list[float]:
    return [round(c, 3) for c in colorsys.hsv_to_rgb(h % 1.0, s, v)] + [1.0]


def _loft(house: House, rng: np.random.Generator) -> HouseLook:
    """Saturated speckled walls, dark checkered floors, a dimmer light from the other side."""
    n = len(house.rooms)
    u = rng.uniform
    walls = [_hsv(u(0, 1), u(0.55, 0.85), u(0.55, 0.85)) for _ in range(n)]
    floor_hue = u(0, 1)
    floors = [_hsv(floor_hue + u(-0.08, 0.08), u(0.15, 0.45), u(0.22, 0.38)) for _ in range(n)]
    wood = _hsv(u(0.02, 0.10), u(0.3, 0.6), u(0.12, 0.22))  # dark walnut
    legs = _hsv(0.0, 0.0, u(0.72, 0.85))  # brushed steel
    finishes = {
        "wood": tuple(wood),
        "legs": tuple(legs),
        "metal": tuple(_hsv(u(0.09, 0.13), u(0.5, 0.7), u(0.55, 0.7))),  # brass
        "dark": tuple(_hsv(0.0, 0.0, u(0.45, 0.55))),  # mid grey instead of black
        "screen": tuple(_hsv(u(0.55, 0.65), u(0.4, 0.6), u(0.25, 0.35))),  # a lit screen
        "linen": tuple(_hsv(u(0.05, 0.12), u(0.15, 0.3), u(0.55, 0.7))),  # oatmeal
        "pot": tuple(_hsv(u(0.5, 0.6), u(0.1, 0.25), u(0.6, 0.75))),  # blue-grey ceramic
    }
    return HouseLook(
        wall_rgba=walls,
        floor_rgba=floors,
        wall_ext_rgba=tuple(_hsv(u(0, 1), 0.4, 0.5)),
        floor_base_rgba=(0.1, 0.1, 0.1, 1.0),
        floor_specular=0.5,
        wall_texture=Texture(
            "wall_tex",
            "flat",
            (1.0, 1.0, 1.0),
            (1.0, 1.0, 1.0),
            64,
            1.0,
            mark="random",
            markrgb=(0.55, 0.55, 0.55),
            random=0.25,
        ),  # fmt: skip
        floor_texture=Texture("floor_tex", "checker", (1.0, 1.0, 1.0), (0.45, 0.45, 0.45), 2, 2.0),
        headlight_ambient=round(u(0.25, 0.32), 3),
        headlight_diffuse=round(u(0.4, 0.5), 3),
        sun_diffuse=0.7,
        sun_dir=(-0.4, -0.3, -1.0),
        finishes=finishes,
    )
