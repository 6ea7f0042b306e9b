"""Pinhole camera maths: intrinsics from a field of view, depth -> points, pose transforms.

Conventions (Habitat / MuJoCo, shared with the world in ``vla_gr.envs``):

- ``depth`` is planar z-depth along the optical axis in metres; image row 0 is the top.
- Pixel ``(v, u)`` (row, col) has its centre at ``(u + 0.5, v + 0.5)``; the principal point
  is the image centre ``(W / 2, H / 2)``.
- The camera sits ``camera_height`` metres above the floor (plus ``forward_offset`` along the
  heading) and looks horizontally along the robot's heading.
- A pose is ``(x, y, yaw)`` in the map frame: x forward at the episode start, y left, yaw
  counter-clockwise. World points are ``(x, y, z)`` with z the height above the floor.
- The robot (egocentric) frame has x forward, y left, z up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from vla_gr.geometry.robot_spec import CAMERA_HEIGHT, MAX_DEPTH, MIN_DEPTH


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int


def intrinsics_from_hfov(width: int, height: int, hfov_deg: float) -> Intrinsics:
    """Square-pixel pinhole intrinsics of a ``width`` x ``height`` image with HFOV in degrees."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got width={width}, height={height}")
    if not 0.0 < hfov_deg < 180.0:
        raise ValueError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
    fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return Intrinsics(fx=fx, fy=fx, cx=width / 2.0, cy=height / 2.0, width=width, height=height)


def valid_depth_mask(depth: torch.Tensor, min_depth: float, max_depth: float) -> torch.Tensor:
    """Bool mask (same shape as ``depth``): finite and in ``[min_depth, max_depth)``.

    Depth at ``max_depth`` is a clipped no-return (Habitat convention) and is masked too.
    """
    return torch.isfinite(depth) & (depth >= min_depth) & (depth < max_depth)


def depth_to_camera_points(depth: torch.Tensor, hfov_deg: float) -> torch.Tensor:
    """Back-project planar depth into the robot-aligned camera frame.

    Args:
        depth: (B, H, W) z-depth in metres (invalid values are passed through; mask them).
        hfov_deg: horizontal field of view in degrees.

    Returns:
        (B, H, W, 3) points as (forward, left, up) relative to the optical centre.
    """
    if depth.ndim != 3:
        raise ValueError(f"depth must be (B, H, W), got shape {tuple(depth.shape)}")
    _, H, W = depth.shape
    K = intrinsics_from_hfov(W, H, hfov_deg)
    u = torch.arange(W, device=depth.device, dtype=depth.dtype) + 0.5  # (W,)
    v = torch.arange(H, device=depth.device, dtype=depth.dtype) + 0.5  # (H,)
    right = ((u - K.cx) / K.fx)[None, None, :] * depth  # (B, H, W)
    down = ((v - K.cy) / K.fy)[None, :, None] * depth  # (B, H, W)
    return torch.stack([depth, -right, -down], dim=-1)  # (B, H, W, 3)


def ego_to_world(points: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
    """Rotate and translate egocentric points into the map frame.

    Args:
        points: (B, N, D) with D >= 2; the first two entries are (forward, left), any further
            entries (e.g. height) are copied unchanged.
        pose: (B, 3) as (x, y, yaw).

    Returns:
        (B, N, D) map-frame points.
    """
    _check_pose(pose, points.shape[0])
    c = torch.cos(pose[:, 2:3])  # (B, 1)
    s = torch.sin(pose[:, 2:3])  # (B, 1)
    fx, ly = points[..., 0], points[..., 1]  # (B, N)
    x = pose[:, 0:1] + c * fx - s * ly  # (B, N)
    y = pose[:, 1:2] + s * fx + c * ly  # (B, N)
    return torch.cat([x[..., None], y[..., None], points[..., 2:]], dim=-1)  # (B, N, D)


def world_to_ego(points: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`ego_to_world`: map-frame points (B, N, D) -> egocentric (B, N, D)."""
    _check_pose(pose, points.shape[0])
    c = torch.cos(pose[:, 2:3])  # (B, 1)
    s = torch.sin(pose[:, 2:3])  # (B, 1)
    dx = points[..., 0] - pose[:, 0:1]  # (B, N)
    dy = points[..., 1] - pose[:, 1:2]  # (B, N)
    fwd = c * dx + s * dy  # (B, N)
    left = -s * dx + c * dy  # (B, N)
    return torch.cat([fwd[..., None], left[..., None], points[..., 2:]], dim=-1)  # (B, N, D)


def project_depth(
    depth: torch.Tensor,
    hfov_deg: float,
    pose: torch.Tensor,
    camera_height: float = CAMERA_HEIGHT,
    forward_offset: float = 0.0,
    min_depth: float = MIN_DEPTH,
    max_depth: float = MAX_DEPTH,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth images -> map-frame 3-D points with a validity mask.

    Args:
        depth: (B, H, W) or (B, H, W, 1) planar depth in metres; NaN, inf, values below
            ``min_depth`` or above ``max_depth`` are masked out (their points are set to 0).
        hfov_deg: horizontal field of view in degrees.
        pose: (B, 3) robot pose (x, y, yaw) in the map frame.
        camera_height: optical centre height above the floor (m).
        forward_offset: optical centre offset along the heading from the robot centre (m).
        min_depth, max_depth: accepted depth range (m).

    Returns:
        points (B, N, 3) as (x, y, height) with N = H * W in row-major pixel order, and
        valid (B, N) bool.
    """
    if depth.ndim == 4 and depth.shape[-1] == 1:
        depth = depth[..., 0]
    if depth.ndim != 3:
        raise ValueError(f"depth must be (B, H, W) or (B, H, W, 1), got {tuple(depth.shape)}")
    if min_depth < 0 or max_depth <= min_depth:
        raise ValueError(f"need 0 <= min_depth < max_depth, got {min_depth}, {max_depth}")
    B = depth.shape[0]
    _check_pose(pose, B)
    depth = depth.to(pose.dtype) if depth.is_floating_point() else depth.float()
    valid = valid_depth_mask(depth, min_depth, max_depth)  # (B, H, W)
    clean = torch.where(valid, depth, torch.zeros_like(depth))  # (B, H, W)
    cam = depth_to_camera_points(clean, hfov_deg)  # (B, H, W, 3)
    offset = torch.tensor([forward_offset, 0.0, camera_height], dtype=cam.dtype, device=cam.device)
    ego = (cam + offset).reshape(B, -1, 3)  # (B, N, 3)
    world = ego_to_world(ego, pose.to(cam.dtype))  # (B, N, 3)
    valid = valid.reshape(B, -1)  # (B, N)
    world = torch.where(valid[..., None], world, torch.zeros_like(world))  # (B, N, 3)
    return world, valid


def column_bearings(width: int, hfov_deg: float) -> torch.Tensor:
    """Bearing (W,) in radians (counter-clockwise from the optical axis) of each pixel column."""
    K = intrinsics_from_hfov(width, width, hfov_deg)
    u = torch.arange(width, dtype=torch.float64) + 0.5  # (W,)
    return torch.atan(-(u - K.cx) / K.fx)  # (W,)


def _check_pose(pose: torch.Tensor, batch: int) -> None:
    if pose.ndim != 2 or pose.shape != (batch, 3):
        raise ValueError(f"pose must be (B={batch}, 3) as (x, y, yaw), got {tuple(pose.shape)}")


def box_room_depth(
    pose, room: tuple[float, float, float, float], size: int, hfov_deg: float, camera_height: float
) -> np.ndarray:
    """Analytic planar depth (size, size) of an empty box room with a floor, seen from ``pose``.

    ``room`` = (x0, x1, y0, y1) wall positions (m), ``pose`` = (x, y, yaw) inside it; the
    camera looks horizontally at ``camera_height``. Rays that hit nothing are ``inf``. For
    tests and benchmarks of the mapping without a simulator.
    """
    K = intrinsics_from_hfov(size, size, hfov_deg)
    px, py, yaw = pose
    a = np.arange(size) + 0.5  # (S,)
    left = np.broadcast_to(-(a - K.cx) / K.fx, (size, size))  # (S, S) per unit depth
    up = np.broadcast_to((-(a - K.cy) / K.fy)[:, None], (size, size))  # (S, S)
    dx, dy = np.cos(yaw) - np.sin(yaw) * left, np.sin(yaw) + np.cos(yaw) * left  # (S, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = [(room[0] - px) / dx, (room[1] - px) / dx, (room[2] - py) / dy, (room[3] - py) / dy]
        ts.append(np.where(up < 0, camera_height / -up, np.inf))
    ts = np.stack([np.where(t > 1e-9, t, np.inf) for t in ts])  # (5, S, S)
    return ts.min(axis=0).astype(np.float32)  # (S, S)
