"""Per-pixel object-category labels of stored frames, from the world's geometry.

A stored frame keeps its depth and its pose (relative to the episode start), and the
episode's spec regenerates its house. Every pixel is back-projected to a 3-D point in the
world; a point inside an object's oriented footprint (grown by ``margin``), above the floor
and below the object's top is labelled with that object's category. Everything else (walls,
floor, the space under a table, no-return pixels) is background, label 0. The renderer's own
segmentation agrees with these labels on most pixels (``tests/training/test_object_labels``),
and no store needs re-rendering.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from vla_gr.geometry.robot_spec import HFOV_DEG

__all__ = ["frame_categories", "house_of"]

#: Points lower than this (m) are floor, never an object.
FLOOR_HEIGHT = 0.03


def house_of(spec: dict, houses: dict):
    """The house of episode ``spec``, regenerated once and cached in ``houses`` (one entry:
    a store keeps the episodes of one house together)."""
    from vla_gr.envs.episodes import EpisodeSpec
    from vla_gr.envs.house import generate_house

    s = EpisodeSpec.from_dict(spec)
    if s.scene_key not in houses:
        houses.clear()
        houses[s.scene_key] = generate_house(s.scene_seed, num_rooms=s.num_rooms, clutter=s.clutter)
    return s, houses[s.scene_key]


def frame_categories(
    spec: dict,
    poses: np.ndarray,
    depth: np.ndarray,
    categories: Sequence[str],
    houses: dict,
    margin: float = 0.04,
) -> np.ndarray:
    """Category labels (T, H, W) uint8 of one episode's frames: 0 = background, k = the
    object category ``categories[k - 1]``.

    Args:
        spec: the episode spec (a stored ``EpisodeSpec`` dict).
        poses: (T, 3) stored poses, relative to the episode start.
        depth: (T, H, W) or (T, H, W, 1) planar depth in metres.
        categories: the category order of the labels.
        houses: a cache for :func:`house_of`.
        margin: metres a footprint is grown by (surface points sit on its edge).
    """
    from vla_gr.geometry.camera import project_depth
    from vla_gr.geometry.pose2d import robot_to_map

    s, house = house_of(spec, houses)
    depth = np.asarray(depth, np.float32)
    depth = depth[..., 0] if depth.ndim == 4 else depth  # (T, H, W)
    T, H, W = depth.shape
    poses = np.asarray(poses, np.float64)  # (T, 3)
    world = np.empty_like(poses)  # (T, 3) world poses
    world[:, :2] = robot_to_map(poses[:, :2], s.start_pose)
    world[:, 2] = poses[:, 2] + s.start_pose[2]
    points, valid = project_depth(torch.from_numpy(depth).double(), HFOV_DEG,
                                  torch.from_numpy(world))  # fmt: skip
    points, valid = points.numpy().reshape(-1, 3), valid.numpy().reshape(-1)  # (N, 3), (N,)
    labels = np.zeros(T * H * W, np.uint8)  # (N,)
    order = list(categories)
    candidates = valid & (points[:, 2] > FLOOR_HEIGHT)  # (N,)
    for obj in house.objects:
        if obj.category not in order:
            continue
        c, si = np.cos(obj.yaw), np.sin(obj.yaw)
        dx, dy = points[:, 0] - obj.x, points[:, 1] - obj.y  # (N,)
        hx, hy = obj.half_extents
        inside = (
            candidates
            & (np.abs(c * dx + si * dy) <= hx + margin)
            & (np.abs(-si * dx + c * dy) <= hy + margin)
            & (points[:, 2] <= obj.height + margin)
        )  # (N,)
        labels[inside] = order.index(obj.category) + 1
    return labels.reshape(T, H, W)
