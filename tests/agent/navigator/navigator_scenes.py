"""Synthetic scenes for the navigator's tests: a box room seen from a pose, a goal on its
wall, and a navigator ticked on them."""

import dataclasses

import numpy as np

from vla_gr.agent.followers.pure_pursuit import PursuitConfig
from vla_gr.agent.navigator.navigator import Navigator, NavigatorConfig
from vla_gr.core.gr_field import GRFieldConfig
from vla_gr.geometry.camera import box_room_depth, intrinsics_from_hfov

HFOV, CAM_H, N = 79.0, 0.88, 32
ROOM = (-3.0, 3.0, -2.0, 2.0)  # x0, x1, y0, y1 of a box room around the start (m)
LOOKAHEAD = PursuitConfig().lookahead  # the follower's (model.pursuit.lookahead)


def room_depth(pose, room=ROOM, n=N):
    """Analytic z-depth (n, n, 1) of an axis-aligned box room with a floor seen from ``pose``."""
    return box_room_depth(pose, room, n, HFOV, CAM_H)[..., None]


def wall_goal(depth):
    """Likelihood (n, n): 1 on the central columns' wall pixels (not floor), else 0."""
    n = depth.shape[0]
    K = intrinsics_from_hfov(n, n, HFOV)
    height = CAM_H - ((np.arange(n) + 0.5 - K.cy) / K.fy)[:, None] * depth[..., 0]  # (n, n)
    like = np.zeros((n, n), np.float32)
    cols = slice(n // 2 - 3, n // 2 + 3)
    like[:, cols] = (height[:, cols] > 0.15).astype(np.float32)
    return like


def navigator_config(**sections) -> NavigatorConfig:
    """The default ``NavigatorConfig`` with ``sections`` changed: a section as a dict of its
    keys (``approach={"stop_distance": 0.8}`` is ``model.navigator.approach.stop_distance``),
    a top-level key (``turn_rate``) as its value."""
    base = NavigatorConfig()
    return NavigatorConfig(**{
        name: dataclasses.replace(getattr(base, name), **value) if isinstance(value, dict)
        else value
        for name, value in sections.items()
    })  # fmt: skip


def make_nav(**sections) -> Navigator:
    """A navigator with :func:`navigator_config` of ``sections`` on a small 64 x 64 map of
    0.15 m cells."""
    fcfg = GRFieldConfig(map_size=64, cell_size=0.15, ego_size=16)
    return Navigator(navigator_config(**sections), fcfg, lookahead=LOOKAHEAD)


def tick(nav, pose, like=None, visible=1.0):
    """One planner tick of ``nav`` at ``pose`` in the box room, with the goal likelihood
    ``like`` (n, n) (none by default) and the head's "goal visible" probability ``visible``."""
    depth = room_depth(pose)
    if like is None:
        like = np.zeros(depth.shape[:2], np.float32)
    return nav.plan({"depth": depth, "pose": np.array(pose, np.float32)}, like, visible)
