"""House styles: the default is today's world byte for byte; the held-out ``loft`` changes the
look (deterministically per house) and never geometry, labels or an object's named colour."""

import colorsys
import hashlib
import re

import gymnasium as gym
import numpy as np
import pytest

import vla_gr.envs  # noqa: F401 - registers the env id
from vla_gr.envs import robot as rb
from vla_gr.envs.house import generate_house, house_to_mjcf
from vla_gr.envs.house_style import FINISHES, HOUSE_STYLES, house_look
from vla_gr.envs.scene import COLORS

# Recorded with the code before house styles existed (commit 734076c): house 2 holds every
# furniture category; val episode 7 after five steps of (0.6, 0.3) at 64 px.
MJCF_HOUSE_2_SHA256 = "49cbfb461a8ad87539c6ed1c370f700827833becf7d1c9d5857c33cff5b4ee5e"
FRAME_RGB_SHA256 = "1ceb4ed553eabca96fbf43c551a2576a0d9798293c26761818e2605f0bf4067e"
FRAME_DEPTH_SHA256 = "74f927c59d43210918456e24ce2b74fa593b83e095c4b03be5ca26388fed327f"
_GEOM = re.compile(r'<geom name="(obj\d+_\w+)" class="visual"[^>]* rgba="([^"]+)"/>')


def _sha(array: np.ndarray) -> str:
    return hashlib.sha256(array.tobytes()).hexdigest()


def _mjcf(seed: int, style: str) -> str:
    return house_to_mjcf(generate_house(seed), rb.robot_body_xml(64, 64), house_style=style)


def _frame(style: str) -> dict:
    env = gym.make("VLAGR/ObjectNav-v0", split="val", image_size=64, semantic=True,
                   house_style=style)  # fmt: skip
    try:
        obs, _ = env.reset(options={"episode": 7})
        for _ in range(5):
            obs, *_ = env.step(np.array([0.6, 0.3, -1.0], np.float32))
        return obs
    finally:
        env.close()


@pytest.fixture(scope="module")
def frames() -> dict[str, dict]:
    return {style: _frame(style) for style in HOUSE_STYLES}


def test_default_style_is_todays_mjcf():
    assert hashlib.sha256(_mjcf(2, "default").encode()).hexdigest() == MJCF_HOUSE_2_SHA256
    plain = house_to_mjcf(generate_house(2), rb.robot_body_xml(64, 64))
    assert plain == _mjcf(2, "default")


def test_default_style_renders_todays_frame(frames):
    assert _sha(frames["default"]["rgb"]) == FRAME_RGB_SHA256
    assert _sha(frames["default"]["depth"]) == FRAME_DEPTH_SHA256


def test_loft_changes_the_look_not_geometry_or_labels(frames):
    default, loft = frames["default"], frames["loft"]
    assert np.array_equal(default["depth"], loft["depth"])
    assert np.array_equal(default["semantic"], loft["semantic"])
    assert default["instruction"] == loft["instruction"]
    diff = np.abs(default["rgb"].astype(int) - loft["rgb"].astype(int))  # (H, W, 3)
    background = default["semantic"] == 0  # (H, W) walls and floors
    assert diff[background].mean() > 30  # visibly another world


def test_loft_is_deterministic_per_house_and_differs_between_houses():
    assert _mjcf(3, "loft") == _mjcf(3, "loft")
    a, b = house_look(generate_house(3), "loft"), house_look(generate_house(4), "loft")
    assert a.wall_rgba != b.wall_rgba and a.finishes != b.finishes


def test_loft_walls_are_saturated_and_floors_dark():
    for seed in range(6):
        house = generate_house(seed)
        default, loft = house_look(house, "default"), house_look(house, "loft")
        sat = [colorsys.rgb_to_hsv(*c[:3])[1] for c in loft.wall_rgba]
        assert min(sat) >= 0.5 > max(colorsys.rgb_to_hsv(*c[:3])[1] for c in default.wall_rgba)
        assert max(max(c[:3]) for c in loft.floor_rgba) < min(
            max(c[:3]) for c in default.floor_rgba
        )
        assert loft.wall_texture is not None and loft.floor_texture is not None


def test_named_colours_are_never_restyled_and_finishes_are():
    default = dict(_GEOM.findall(_mjcf(2, "default")))
    loft = dict(_GEOM.findall(_mjcf(2, "loft")))
    assert default.keys() == loft.keys()
    house = generate_house(2)
    from vla_gr.envs.furniture import object_geoms

    named = finished = 0
    for obj in house.objects:
        for g in object_geoms(obj):
            name = f"{obj.body_name}_{g.suffix}"
            if g.finish is None:
                assert loft[name] == default[name], name  # the semantic label stays
                named += 1
            else:
                assert g.finish in FINISHES
                assert loft[name] != default[name], name
                finished += 1
    assert named > 0 and finished > 0
    look = house_look(house, "loft")
    named_rgba = {tuple(round(v, 3) for v in c) for c in COLORS.values()}
    assert not {tuple(round(v, 3) for v in f[:3]) for f in look.finishes.values()} & named_rgba


def test_unknown_style_is_one_line_naming_the_choices():
    with pytest.raises(ValueError, match="house_style='attic'.*default, loft"):
        gym.make("VLAGR/ObjectNav-v0", house_style="attic")
    from vla_gr.configs.schema import EnvConfig

    with pytest.raises(ValueError, match="env.house_style"):
        EnvConfig(house_style="attic")
