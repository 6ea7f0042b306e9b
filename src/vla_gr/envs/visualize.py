"""Pictures of episodes: a top-down map (PNG) with a metre scale, and frames RGB | depth |
top-down over a caption, written as an H.264 MP4 (or GIF bytes, for TensorBoard).

Drawing is numpy + Pillow (no figure machinery), so a frame costs a few milliseconds;
matplotlib is only used for its depth colour map, the ``ffmpeg`` binary encodes MP4.
Map convention: image up = world +y, image right = world +x.
"""

from __future__ import annotations

import logging
import shutil
import subprocess
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from vla_gr.envs.scene import CATEGORIES, House, category_display_name
from vla_gr.geometry.robot_spec import ROBOT_RADIUS

log = logging.getLogger(__name__)

#: Fill colours (RGB uint8) of the map layers; the goal/start/path/robot colours are
#: distinct from every category colour so a pixel's colour identifies what it shows.
OUTSIDE_COLOR = (40, 40, 46)
FLOOR_COLOR = (236, 232, 222)
WALL_COLOR = (90, 90, 96)
GOAL_COLOR = (255, 0, 220)
START_COLOR = (0, 190, 255)
PATH_COLOR = (255, 150, 0)
ROBOT_COLOR = (220, 20, 20)
SCALE_COLOR = (255, 255, 255)  # the metre scale bar and its label
CAPTION_BACKGROUND = (24, 24, 28)
CATEGORY_COLORS: dict[str, tuple[int, int, int]] = {
    "chair": (166, 110, 60),
    "sofa": (120, 90, 170),
    "bed": (110, 160, 210),
    "toilet": (150, 200, 200),
    "tv_monitor": (30, 30, 30),
    "plant": (60, 150, 70),
    "table": (200, 170, 110),
    "cabinet": (130, 100, 80),
}
_OTHER_COLOR = (160, 160, 160)
LEGEND_WIDTH = 110
#: Lengths (m) a scale bar may show.
SCALE_METRES = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)


def font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's built-in font at ``size`` pixels (its fixed bitmap font without FreeType)."""
    return ImageFont.load_default(size=max(8, int(size)))


def scale_bar_metres(px_per_m: float, max_px: float) -> float:
    """The longest of :data:`SCALE_METRES` whose bar spans at most ``max_px`` pixels at
    ``px_per_m`` (the shortest when none fits)."""
    fits = [m for m in SCALE_METRES if m * px_per_m <= max_px]
    return fits[-1] if fits else SCALE_METRES[0]


def depth_to_rgb(depth: np.ndarray, max_depth: float = 5.0) -> np.ndarray:
    """Colour-map metric depth (H, W) or (H, W, 1) to (H, W, 3) uint8 (viridis, near = dark)."""
    from matplotlib import colormaps

    if max_depth <= 0:
        raise ValueError(f"max_depth={max_depth} must be > 0")
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim == 3:
        d = d[..., 0]
    if d.ndim != 2:
        raise ValueError(f"depth must be (H, W) or (H, W, 1), got {np.shape(depth)}")
    lut = (colormaps["viridis"](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint8)  # (256, 3)
    idx = np.clip(np.nan_to_num(d, nan=max_depth, posinf=max_depth) / max_depth, 0, 1)
    return lut[(idx * 255).astype(np.int64)]  # (H, W, 3)


class TopDownMap:
    """A house's static top-down map at ``size`` x ``size`` pixels, with overlays drawn on demand.

    The base layer (floor, walls, objects by category, the goal highlighted, a metre scale
    bar) is rendered once; ``draw`` adds start, trajectory and robot and an optional legend.
    """

    def __init__(self, house: House, goal_id: int | None = None, size: int = 256) -> None:
        if size < 16:
            raise ValueError(f"size={size} must be >= 16 pixels")
        self.house, self.goal_id, self.size = house, goal_id, size
        grid = house.grid
        self.px_per_m = size / (max(grid.height, grid.width) * grid.cell_size)
        # Pixel offsets that centre the (possibly non-square) grid in the square image.
        self._u0 = (size - grid.width * grid.cell_size * self.px_per_m) / 2
        self._v0 = (size - grid.height * grid.cell_size * self.px_per_m) / 2
        self.base = self._render_base()  # (size, size, 3)

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """World points (..., 2) as (x, y) -> pixel coordinates (..., 2) as (u=col, v=row)."""
        g = self.house.grid
        xy = np.asarray(xy, dtype=np.float64)
        u = self._u0 + (xy[..., 0] - g.origin_x) * self.px_per_m
        v = self._v0 + (g.origin_y + g.height * g.cell_size - xy[..., 1]) * self.px_per_m
        return np.stack([u, v], axis=-1)

    def _cell_layer(self) -> np.ndarray:
        """Colour per grid cell (Hc, Wc, 3) uint8, rows already flipped (top = +y)."""
        house = self.house
        g = house.grid
        img = np.empty((g.height, g.width, 3), np.uint8)
        img[:] = OUTSIDE_COLOR
        xs, ys = g.cell_centres()  # (Hc, Wc) each
        for room in house.rooms:
            inside = (xs >= room.x0) & (xs <= room.x1) & (ys >= room.y0) & (ys <= room.y1)
            img[inside] = FLOOR_COLOR
        ids = np.asarray(house.object_ids)
        img[np.asarray(house.occupancy, bool) & (ids == 0)] = WALL_COLOR
        for obj in house.objects:
            img[ids == obj.instance_id] = CATEGORY_COLORS.get(obj.category, _OTHER_COLOR)
        if self.goal_id is not None:
            img[ids == self.goal_id] = GOAL_COLOR
        return img[::-1]

    def _render_base(self) -> np.ndarray:
        cells = self._cell_layer()  # (Hc, Wc, 3)
        g = self.house.grid
        w = max(1, round(g.width * g.cell_size * self.px_per_m))
        h = max(1, round(g.height * g.cell_size * self.px_per_m))
        scaled = np.asarray(Image.fromarray(cells).resize((w, h), Image.NEAREST))  # (h, w, 3)
        out = np.empty((self.size, self.size, 3), np.uint8)
        out[:] = OUTSIDE_COLOR
        u0, v0 = int(round(self._u0)), int(round(self._v0))
        out[v0 : v0 + h, u0 : u0 + w] = scaled[: self.size - v0, : self.size - u0]
        img = Image.fromarray(out)
        if self.goal_id is not None:
            obj = self.house.object(self.goal_id)
            draw = ImageDraw.Draw(img)
            c = self.to_pixel([obj.x, obj.y])
            r = max(6.0, (max(obj.half_extents) + 0.25) * self.px_per_m)
            draw.ellipse([c[0] - r, c[1] - r, c[0] + r, c[1] + r], outline=GOAL_COLOR, width=2)
        self._draw_scale_bar(ImageDraw.Draw(img))
        return np.asarray(img)

    def _draw_scale_bar(self, draw: ImageDraw.ImageDraw) -> None:
        """A bar of :func:`scale_bar_metres` metres and its label ("2 m") in the bottom-left
        corner, on a dark box so that it reads over floor or outside alike."""
        metres = scale_bar_metres(self.px_per_m, self.size / 4)
        length = max(1, round(metres * self.px_per_m))  # pixels
        pad, thick = max(2, self.size // 64), max(2, self.size // 80)
        label_font = font(self.size // 20)
        label = f"{metres:g} m"
        _, top, right, bottom = draw.textbbox((0, 0), label, font=label_font)
        x0, y0 = 2 * pad, self.size - 2 * pad - thick  # the bar's top-left pixel
        box = [
            x0 - pad,
            y0 - (bottom - top) - 3 * pad,
            x0 + max(length, right) + pad,
            y0 + thick + pad,
        ]
        draw.rectangle(box, fill=OUTSIDE_COLOR)
        draw.rectangle([x0, y0, x0 + length - 1, y0 + thick - 1], fill=SCALE_COLOR)
        draw.text((x0, y0 - pad - bottom), label, fill=SCALE_COLOR, font=label_font)

    def draw(
        self,
        trajectory: np.ndarray | None = None,
        start: Sequence[float] | None = None,
        robot: Sequence[float] | None = None,
        legend: bool = False,
    ) -> np.ndarray:
        """Map with overlays -> (size, size [+ LEGEND_WIDTH], 3) uint8.

        trajectory: (N, 2) world (x, y) polyline; start, robot: (x, y) or (x, y, yaw).
        """
        img = Image.fromarray(self.base.copy())
        draw = ImageDraw.Draw(img)
        r = max(3.0, ROBOT_RADIUS * self.px_per_m)  # robot radius in pixels, at least 3
        if trajectory is not None and len(trajectory) > 1:
            pts = self.to_pixel(np.asarray(trajectory, dtype=np.float64)[:, :2])  # (N, 2)
            width = max(1, int(round(r / 2)))
            draw.line([tuple(p) for p in pts], fill=PATH_COLOR, width=width, joint="curve")
        for pose, color in ((start, START_COLOR), (robot, ROBOT_COLOR)):
            if pose is None:
                continue
            c = self.to_pixel(np.asarray(pose[:2], dtype=np.float64))
            draw.ellipse([c[0] - r, c[1] - r, c[0] + r, c[1] + r], fill=color)
            if len(pose) > 2:
                tip = c + 1.8 * r * np.array([np.cos(pose[2]), -np.sin(pose[2])])
                draw.line([tuple(c), tuple(tip)], fill=color, width=max(1, int(r / 2)))
        out = np.asarray(img)
        if legend:
            out = np.concatenate([out, self._legend()], axis=1)
        return out

    def _legend(self) -> np.ndarray:
        present = [c for c in CATEGORIES if any(o.category == c for o in self.house.objects)]
        entries = [(category_display_name(c), CATEGORY_COLORS[c]) for c in present]
        entries += [
            ("goal", GOAL_COLOR),
            ("start", START_COLOR),
            ("path", PATH_COLOR),
            ("robot", ROBOT_COLOR),
            ("wall", WALL_COLOR),
        ]
        img = Image.new("RGB", (LEGEND_WIDTH, self.size), (255, 255, 255))
        draw = ImageDraw.Draw(img)
        font = ImageFont.load_default()
        step = max(10, min(16, (self.size - 4) // max(1, len(entries))))
        for i, (name, color) in enumerate(entries):
            y = 4 + i * step
            if y + step > self.size:
                break
            draw.rectangle([4, y, 4 + step - 4, y + step - 4], fill=color, outline=(0, 0, 0))
            draw.text((step + 4, y - 1), name, fill=(0, 0, 0), font=font)
        return np.asarray(img)


def draw_top_down(
    house: House,
    trajectory: np.ndarray | None = None,
    start: Sequence[float] | None = None,
    goal_id: int | None = None,
    robot: Sequence[float] | None = None,
    size: int = 256,
    legend: bool = True,
) -> np.ndarray:
    """Top-down picture of ``house`` -> (size, size [+ LEGEND_WIDTH], 3) uint8.

    A metre scale bar, walls, objects coloured by category (legend on the right), the goal
    object ``goal_id`` in ``GOAL_COLOR`` with a ring, ``start`` (x, y[, yaw]) in
    ``START_COLOR``, the ``trajectory`` (N, 2) in ``PATH_COLOR`` and the ``robot`` (x, y[, yaw])
    in ``ROBOT_COLOR``.
    """
    return TopDownMap(house, goal_id, size).draw(trajectory, start, robot, legend)


def save_top_down_png(path: str | Path, house: House, **kwargs) -> Path:
    """Write ``draw_top_down(house, **kwargs)`` to ``path`` (PNG); returns the path."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, draw_top_down(house, **kwargs))
    return path


def _to_panel(img: np.ndarray, size: int) -> np.ndarray:
    """Nearest-resize (h, w, 3) uint8 to (size, size, 3)."""
    if img.shape[:2] == (size, size):
        return img
    return np.asarray(Image.fromarray(img).resize((size, size), Image.NEAREST))


def caption_band(lines: Sequence[str], width: int, font_size: int) -> np.ndarray:
    """``lines`` of text, light on dark, as a (len(lines) * line height + padding, width, 3)
    uint8 band (an even height); a line too long for ``width`` is cut and ends in "…"."""
    face = font(font_size)
    line_h = int(round(font_size * 1.35))
    pad = max(2, font_size // 3)
    height = len(lines) * line_h + 2 * pad
    img = Image.new("RGB", (width, height + height % 2), CAPTION_BACKGROUND)
    draw = ImageDraw.Draw(img)
    for i, line in enumerate(lines):
        draw.text((pad, pad + i * line_h), _fit(line, face, width - 2 * pad), fill=(240, 240, 240),
                  font=face)  # fmt: skip
    return np.asarray(img)


def _fit(text: str, face, width: float) -> str:
    """``text``, cut to end in "…" when it is wider than ``width`` pixels in ``face``."""
    if face.getlength(text) <= width:
        return text
    while text and face.getlength(text + "…") > width:
        text = text[:-1]
    return text + "…"


class EpisodeRecorder:
    """Collects frames RGB | depth | top-down (path so far, robot, goal, scale) side by side,
    over a caption band of ``caption_lines`` lines when there are any.

    Each frame is (panel [+ band], 3 * panel, 3) uint8; every frame has the same shape.
    """

    def __init__(
        self,
        house: House,
        goal_id: int | None = None,
        start: Sequence[float] | None = None,
        panel: int = 128,
        max_depth: float = 5.0,
        caption_lines: int = 0,
    ) -> None:
        self.map = TopDownMap(house, goal_id, panel)
        self.start = None if start is None else tuple(float(v) for v in start)
        self.panel, self.max_depth, self.caption_lines = panel, max_depth, caption_lines
        self.font_size = max(9, panel // 18)
        self.frames: list[np.ndarray] = []
        self._path: list[tuple[float, float]] = []

    def add(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        robot_pose: Sequence[float],
        caption: Sequence[str] = (),
    ) -> np.ndarray:
        """Append a frame from rgb (H, W, 3) uint8, depth (H, W[, 1]) metres, the robot's
        world pose (x, y, yaw) and at most ``caption_lines`` lines of caption; returns it."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[-1] != 3:
            raise ValueError(f"rgb must be (H, W, 3), got {rgb.shape}")
        if len(caption) > self.caption_lines:
            raise ValueError(f"{len(caption)} caption lines, the recorder has {self.caption_lines}")
        self._path.append((float(robot_pose[0]), float(robot_pose[1])))
        top = self.map.draw(np.array(self._path), self.start, robot_pose)  # (P, P, 3)
        frame = np.concatenate(
            [
                _to_panel(rgb.astype(np.uint8), self.panel),
                _to_panel(depth_to_rgb(depth, self.max_depth), self.panel),
                top,
            ],
            axis=1,
        )  # (P, 3P, 3)
        if self.caption_lines:
            lines = [*caption, *[""] * (self.caption_lines - len(caption))]
            band = caption_band(lines, frame.shape[1], self.font_size)  # (B, 3P, 3)
            frame = np.concatenate([frame, band], axis=0)  # (P + B, 3P, 3)
        self.frames.append(frame)
        return frame


def _frame_stack(frames: Sequence[np.ndarray], fps: float) -> np.ndarray:
    """Frames (each (H, W, 3), same shape) as one (N, H, W, 3) uint8 array; ValueError if
    there are none, their shapes differ or ``fps`` is not positive."""
    if len(frames) == 0:
        raise ValueError("a video needs at least one frame")
    if fps <= 0:
        raise ValueError(f"fps={fps} must be > 0")
    shapes = {np.shape(f) for f in frames}
    if len(shapes) != 1:
        raise ValueError(f"all frames must have the same shape, got {sorted(shapes)}")
    stack = np.stack([np.asarray(f, dtype=np.uint8) for f in frames])  # (N, H, W, C)
    if stack.ndim != 4 or stack.shape[-1] != 3:
        raise ValueError(f"frames must be (H, W, 3), got {stack.shape[1:]}")
    return stack


def save_mp4(path: str | Path, frames: Sequence[np.ndarray], fps: float = 10.0) -> Path:
    """Write frames (each (H, W, 3) uint8, same shape) as an H.264 MP4 at ``fps``: yuv420p
    (odd sizes padded by one pixel), the index first (``+faststart``), as browsers play it.

    Needs the ``ffmpeg`` binary (Debian's ``ffmpeg``, which ``make setup`` installs).
    """
    stack = _frame_stack(frames, fps)  # (N, H, W, 3)
    exe = shutil.which("ffmpeg")
    if exe is None:
        raise FileNotFoundError("no ffmpeg on PATH to encode MP4 (Debian: apt-get install ffmpeg)")
    n, h, w, _ = stack.shape
    stack = np.pad(stack, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    rate = Fraction(fps).limit_denominator(1000)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    cmd = [
        exe, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
        "-s", f"{w + w % 2}x{h + h % 2}", "-r", str(rate), "-i", "-",
        "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "23", "-preset", "veryfast",
        "-movflags", "+faststart", str(tmp),
    ]  # fmt: skip
    done = subprocess.run(cmd, input=stack.tobytes(), capture_output=True, check=False)
    if done.returncode != 0:
        tmp.unlink(missing_ok=True)
        why = done.stderr.decode(errors="replace").strip().splitlines()[-1:] or ["no message"]
        raise RuntimeError(f"ffmpeg could not write {path}: {why[0]}")
    tmp.replace(path)
    log.info("wrote %s (%d frames)", path, n)
    return path


def gif_bytes(frames: Sequence[np.ndarray], fps: float = 10.0) -> bytes:
    """Frames (each (H, W, 3) uint8, same shape) as a looping GIF at ``fps`` (bytes)."""
    import imageio.v3 as iio

    stack = _frame_stack(frames, fps)  # (N, H, W, 3)
    return iio.imwrite("<bytes>", stack, extension=".gif", duration=1000.0 / fps, loop=0)
