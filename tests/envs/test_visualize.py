"""Top-down map, scale bar, captioned frames, MP4 and GIF: the right colours in the right
pixels, the right bar length, the right frame count and size after encoding."""

import io
import shutil
import subprocess

import imageio.v3 as iio
import numpy as np
import pytest
from PIL import Image

from tests.video_probe import probe
from vla_gr.envs.scene import House, ObjectInstance, Room
from vla_gr.envs.visualize import (
    CATEGORY_COLORS,
    GOAL_COLOR,
    LEGEND_WIDTH,
    PATH_COLOR,
    ROBOT_COLOR,
    SCALE_COLOR,
    START_COLOR,
    WALL_COLOR,
    EpisodeRecorder,
    TopDownMap,
    caption_band,
    depth_to_rgb,
    draw_top_down,
    gif_bytes,
    save_mp4,
    save_top_down_png,
    scale_bar_metres,
)
from vla_gr.geometry import GridSpec


def hand_house() -> House:
    """A 4 m x 3 m room (walls 0.1 m thick) with a red chair and a green plant."""
    grid = GridSpec(origin_x=-0.2, origin_y=-0.2, cell_size=0.05, height=68, width=88)
    xs, ys = grid.cell_centres()
    inside = (xs > 0) & (xs < 4) & (ys > 0) & (ys < 3)
    ring = (xs > -0.1) & (xs < 4.1) & (ys > -0.1) & (ys < 3.1) & ~inside
    objects = [
        ObjectInstance(1, "chair", "red", 0, 1.0, 1.0, 0.0, (0.25, 0.25), 0.9),
        ObjectInstance(2, "plant", "green", 0, 3.0, 2.0, 0.0, (0.2, 0.2), 1.0),
    ]
    ids = np.zeros(grid.shape, np.int32)
    for o in objects:
        hx, hy = o.half_extents
        ids[(abs(xs - o.x) <= hx) & (abs(ys - o.y) <= hy)] = o.instance_id
    return House(
        seed=0,
        rooms=[Room(0, "bedroom", 0.0, 0.0, 4.0, 3.0)],
        doors=[],
        objects=objects,
        grid=grid,
        occupancy=ring | (ids > 0),
        object_ids=ids,
    )


def _at(img, m: TopDownMap, x, y):
    u, v = np.round(m.to_pixel([x, y])).astype(int)
    return tuple(int(c) for c in img[v, u])


def test_top_down_colours_at_known_places():
    house = hand_house()
    m = TopDownMap(house, goal_id=2, size=200)
    traj = np.array([[0.5, 2.5], [2.0, 2.5], [2.0, 1.0]])
    img = draw_top_down(
        house,
        trajectory=traj,
        start=(0.5, 2.5),
        goal_id=2,
        robot=(3.5, 0.5, 0.0),
        size=200,
        legend=True,
    )
    assert img.shape == (200, 200 + LEGEND_WIDTH, 3) and img.dtype == np.uint8
    assert _at(img, m, 3.0, 2.0) == GOAL_COLOR  # goal footprint centre
    assert _at(img, m, 1.0, 1.0) == CATEGORY_COLORS["chair"]  # other object by category
    assert _at(img, m, 0.5, 2.5) == START_COLOR
    assert _at(img, m, 3.5, 0.5) == ROBOT_COLOR
    assert _at(img, m, 2.0, 1.8) == PATH_COLOR  # middle of the second segment
    assert _at(img, m, 4.05, 1.5) == WALL_COLOR  # east wall
    # Up in the image is +y: the plant (y=2) is above the chair (y=1).
    assert m.to_pixel([3.0, 2.0])[1] < m.to_pixel([1.0, 1.0])[1]
    # Without a goal, the plant is drawn in its category colour.
    plain = draw_top_down(house, size=200, legend=False)
    assert plain.shape == (200, 200, 3)
    assert _at(plain, m, 3.0, 2.0) == CATEGORY_COLORS["plant"]
    assert not (plain == np.array(GOAL_COLOR)).all(-1).any()


def test_png_written(tmp_path):
    path = save_top_down_png(tmp_path / "a" / "map.png", hand_house(), goal_id=1, size=64)
    img = iio.imread(path)
    assert img.shape == (64, 64 + LEGEND_WIDTH, 3)


def test_depth_colour_map_is_monotone_and_validated():
    d = np.linspace(0, 5, 10, dtype=np.float32).reshape(1, 10, 1)
    rgb = depth_to_rgb(d)
    assert rgb.shape == (1, 10, 3) and rgb.dtype == np.uint8
    assert len({tuple(c) for c in rgb[0]}) == 10  # distinct colours along the ramp
    with pytest.raises(ValueError, match="max_depth"):
        depth_to_rgb(d, max_depth=0)


def _longest_run(mask: np.ndarray) -> int:
    """Length of the longest horizontal run of True in a (H, W) mask."""
    best = 0
    for row in mask:
        run = 0
        for v in row:
            run = run + 1 if v else 0
            best = max(best, run)
    return best


def test_scale_bar_metres_picks_the_longest_that_fits():
    assert scale_bar_metres(45.0, 50.0) == 1.0
    assert scale_bar_metres(20.0, 60.0) == 2.0
    assert scale_bar_metres(10.0, 64.0) == 5.0
    assert scale_bar_metres(1000.0, 10.0) == 0.5  # none fits: the shortest


@pytest.mark.parametrize("size", [120, 200, 256])
def test_map_scale_bar_is_as_long_as_its_metres(size):
    m = TopDownMap(hand_house(), goal_id=2, size=size)
    metres = scale_bar_metres(m.px_per_m, size / 4)
    bar = (m.base == np.array(SCALE_COLOR)).all(-1)  # (size, size)
    assert abs(_longest_run(bar) - metres * m.px_per_m) <= 1.0
    rows = np.nonzero(bar.any(1))[0]
    assert rows.min() > size * 0.75  # bottom of the map, label above the bar
    assert (m.draw() == np.array(SCALE_COLOR)).all(-1).sum() == bar.sum()  # kept under overlays


def _moving_frames(n: int, panel: int, lines: int = 0, caption=None):
    house = hand_house()
    rec = EpisodeRecorder(house, goal_id=2, start=(0.5, 0.5, 0.0), panel=panel,
                          caption_lines=lines)  # fmt: skip
    rng = np.random.default_rng(0)
    for k in range(n):
        rgb = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
        depth = rng.uniform(0.2, 4.0, (16, 16, 1)).astype(np.float32)
        rec.add(rgb, depth, (0.5 + 0.4 * k, 0.5, 0.0), caption(k) if caption else ())
    return rec


def test_recorder_frames_show_the_robot_moving_in_the_map_panel():
    frames = _moving_frames(6, 48).frames
    assert all(f.shape == (48, 3 * 48, 3) for f in frames)
    # The robot moved east: its colour appears further right in the last top-down panel.
    last = frames[-1][:, 96:, :3]
    cols = np.nonzero((np.abs(last.astype(int) - ROBOT_COLOR).sum(-1) < 30).any(0))[0]
    first = frames[0][:, 96:, :3]
    cols0 = np.nonzero((np.abs(first.astype(int) - ROBOT_COLOR).sum(-1) < 30).any(0))[0]
    assert cols.mean() > cols0.mean() + 10


def test_captions_are_written_under_the_panels():
    rec = _moving_frames(3, 64, lines=2, caption=lambda k: ["find the plant", f"step {k}"])
    f0, f1, f2 = rec.frames
    assert f0.shape == f1.shape and f0.shape[1] == 3 * 64 and f0.shape[0] > 64
    assert f0.shape[0] % 2 == 0  # H.264 in yuv420p needs even sizes
    band0, band1 = f0[64:], f1[64:]
    assert band0.std() > 10  # text, not an empty band
    rows0 = np.nonzero((band0 != band1).any(-1).any(-1))[0]
    assert rows0.size and rows0.min() > (band0.shape[0] // 2) - 4  # only the step line changed
    blank = caption_band(["", ""], 3 * 64, rec.font_size)
    assert blank.shape == band0.shape and (blank == blank[0, 0]).all()
    long = caption_band(["x" * 500], 100, 12)
    assert long.shape[1] == 100  # cut to the width
    with pytest.raises(ValueError, match="caption lines"):
        rec.add(np.zeros((8, 8, 3), np.uint8), np.ones((8, 8)), (0, 0, 0), ["a", "b", "c"])


def _decode(path, w: int, h: int) -> np.ndarray:
    """Frames of a video file (N, h, w, 3) as ffmpeg decodes them."""
    raw = subprocess.run(
        ["ffmpeg", "-loglevel", "error", "-i", str(path), "-f", "rawvideo", "-pix_fmt", "rgb24",
         "-"], capture_output=True, check=True,
    ).stdout  # fmt: skip
    return np.frombuffer(raw, np.uint8).reshape(-1, h, w, 3)


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="no ffmpeg (make setup installs it)")
def test_mp4_is_h264_yuv420p_with_every_frame(tmp_path):
    rec = _moving_frames(7, 48, lines=1, caption=lambda k: [f"step {k}"])
    odd = [f[:-1, :-1] for f in rec.frames]  # odd sizes are padded to even ones
    path = save_mp4(tmp_path / "a" / "ep.mp4", odd, fps=5)
    h, w = odd[0].shape[:2]
    info = probe(path)
    assert info["codec_name"] == "h264" and info["pix_fmt"] == "yuv420p"
    assert (int(info["width"]), int(info["height"])) == (w + w % 2, h + h % 2)
    assert int(info["nb_read_frames"]) == 7
    back = _decode(path, w + w % 2, h + h % 2)[:, :h, :w]  # (7, h, w, 3)
    err = np.abs(back.astype(int) - np.stack(odd).astype(int)).mean(axis=(1, 2, 3))
    assert (err < 20).all()  # lossy, but the same pictures (random noise panels included)
    assert not list(tmp_path.glob("a/.*"))  # no temporary file left


def test_gif_bytes_hold_every_frame_and_the_rate():
    frames = [np.full((10, 12, 3), 40 * k, np.uint8) for k in range(5)]
    gif = Image.open(io.BytesIO(gif_bytes(frames, fps=4)))
    assert gif.size == (12, 10) and gif.n_frames == 5
    assert gif.info["duration"] == 250


def test_video_writers_reject_bad_frames(tmp_path):
    with pytest.raises(ValueError, match="at least one frame"):
        gif_bytes([])
    with pytest.raises(ValueError, match="same shape"):
        save_mp4(tmp_path / "x.mp4", [np.zeros((4, 4, 3)), np.zeros((6, 4, 3))])
    with pytest.raises(ValueError, match="fps"):
        gif_bytes([np.zeros((4, 4, 3))], fps=0)
