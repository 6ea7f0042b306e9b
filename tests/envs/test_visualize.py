"""Top-down map and episode GIF: the right colours in the right pixels, the right frame count."""

import imageio.v3 as iio
import numpy as np
import pytest

from vla_gr.envs.scene import House, ObjectInstance, Room
from vla_gr.envs.visualize import (
    CATEGORY_COLORS,
    GOAL_COLOR,
    LEGEND_WIDTH,
    PATH_COLOR,
    ROBOT_COLOR,
    START_COLOR,
    WALL_COLOR,
    EpisodeRecorder,
    TopDownMap,
    depth_to_rgb,
    draw_top_down,
    save_episode_gif,
    save_top_down_png,
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


def test_gif_frame_count_and_three_panels(tmp_path):
    house = hand_house()
    rec = EpisodeRecorder(house, goal_id=2, start=(0.5, 0.5, 0.0), panel=48)
    rng = np.random.default_rng(0)
    n = 6
    for k in range(n):
        rgb = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
        depth = rng.uniform(0.2, 4.0, (16, 16, 1)).astype(np.float32)
        frame = rec.add(rgb, depth, (0.5 + 0.4 * k, 0.5, 0.0))
        assert frame.shape == (48, 3 * 48, 3)
    path = rec.save(tmp_path / "ep.gif", fps=5)
    frames = iio.imread(path, index=None)
    assert frames.shape[:3] == (n, 48, 3 * 48)
    # The robot moved east: its colour appears further right in the last top-down panel.
    last = frames[-1][:, 96:, :3]
    cols = np.nonzero((np.abs(last.astype(int) - ROBOT_COLOR).sum(-1) < 30).any(0))[0]
    first = frames[0][:, 96:, :3]
    cols0 = np.nonzero((np.abs(first.astype(int) - ROBOT_COLOR).sum(-1) < 30).any(0))[0]
    assert cols.mean() > cols0.mean() + 10


def test_gif_rejects_bad_frames(tmp_path):
    with pytest.raises(ValueError, match="at least one frame"):
        save_episode_gif(tmp_path / "x.gif", [])
    with pytest.raises(ValueError, match="same shape"):
        save_episode_gif(tmp_path / "x.gif", [np.zeros((4, 4, 3)), np.zeros((5, 4, 3))])
