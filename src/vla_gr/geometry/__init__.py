"""Pure grid and camera maths shared by the world (ground truth) and the GR field."""

from vla_gr.geometry.fast_marching import extract_path, geodesic_distance, upwind_gradient
from vla_gr.geometry.grid import (
    GridSpec,
    disk_kernel,
    inflate_obstacles,
)

__all__ = [
    "GridSpec",
    "disk_kernel",
    "inflate_obstacles",
    "geodesic_distance",
    "extract_path",
    "upwind_gradient",
]
