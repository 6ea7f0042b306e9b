"""Top-down RGB picture of a GR field for reports: potential, obstacles, frontier, goal, path.

Last step of the GR field's data flow: an image for reports.
"""

from __future__ import annotations

import numpy as np

_FREE_DIM = 0.35  # brightness of unexplored cells
_OCCUPIED = np.array([25, 25, 25], np.uint8)
_FRONTIER = np.array([0, 220, 255], np.uint8)
_GOAL = np.array([230, 30, 30], np.uint8)
_PATH = np.array([255, 255, 255], np.uint8)
_ROBOT = np.array([255, 150, 0], np.uint8)


def _colormap(values: np.ndarray) -> np.ndarray:
    """Viridis colours (..., 3) uint8 for ``values`` in [0, 1]."""
    from matplotlib import colormaps

    lut = (colormaps["viridis"](np.linspace(0.0, 1.0, 256))[:, :3] * 255).astype(np.uint8)
    idx = np.clip(np.nan_to_num(values, nan=0.0) * 255, 0, 255).astype(np.int64)
    return lut[idx]


def render_field(
    phi_hat: np.ndarray,
    occupied: np.ndarray,
    explored: np.ndarray,
    frontier: np.ndarray,
    goal: np.ndarray,
    path_cells: np.ndarray | None = None,
    robot_cell: tuple[float, float] | None = None,
    heading: float = 0.0,
    scale: int = 2,
) -> np.ndarray:
    """Compose the picture (H * scale, W * scale, 3) uint8 with +y (grid rows) pointing up.

    Args:
        phi_hat: (H, W) potential rescaled to [0, 1] (background colour).
        occupied, explored, frontier, goal: (H, W) bool layers.
        path_cells: (N, 2) fractional (row, col) cell coordinates of the path, or None.
        robot_cell: fractional (row, col) of the robot, or None.
        heading: robot yaw (rad, counter-clockwise from +x).
        scale: integer upsampling factor.
    """
    if scale < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    img = _colormap(phi_hat).astype(np.float32)  # (H, W, 3)
    img[~explored] *= _FREE_DIM
    img = img.astype(np.uint8)
    img[frontier] = _FRONTIER
    img[occupied] = _OCCUPIED
    img[goal] = _GOAL
    img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)  # (H*s, W*s, 3)
    Hs, Ws = img.shape[:2]

    def plot(rows: np.ndarray, cols: np.ndarray, colour: np.ndarray) -> None:
        r = np.floor((rows + 0.5) * scale).astype(np.int64)
        c = np.floor((cols + 0.5) * scale).astype(np.int64)
        ok = (r >= 0) & (r < Hs) & (c >= 0) & (c < Ws)
        img[r[ok], c[ok]] = colour

    if path_cells is not None and len(path_cells) > 1:
        seg = np.diff(path_cells, axis=0)  # (N - 1, 2)
        n = np.maximum(1, np.ceil(np.abs(seg).max(axis=1) * scale * 2)).astype(np.int64)
        pts = np.concatenate(
            [
                p + np.linspace(0, 1, k, endpoint=False)[:, None] * d
                for p, d, k in zip(path_cells[:-1], seg, n)
            ]
            + [path_cells[-1:]]
        )  # (M, 2)
        plot(pts[:, 0], pts[:, 1], _PATH)
    if robot_cell is not None:
        rr, rc = robot_cell
        ang = np.linspace(0, 2 * np.pi, 24)
        for rad in (0.6, 1.0):
            plot(rr + rad * np.sin(ang), rc + rad * np.cos(ang), _ROBOT)
        t = np.linspace(0, 2.5, 10)
        plot(rr + t * np.sin(heading), rc + t * np.cos(heading), _ROBOT)
    return np.ascontiguousarray(img[::-1])
