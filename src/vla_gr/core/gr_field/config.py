"""``GRFieldConfig`` (recipe key ``model.gr_field``) and the channels of the field's features.

Sensor and robot geometry default from :mod:`vla_gr.geometry.robot_spec`. Next in the data
flow: :mod:`vla_gr.core.gr_field.mapping`.
"""

from __future__ import annotations

from dataclasses import dataclass

from vla_gr.geometry.robot_spec import (
    CAMERA_HEIGHT,
    HFOV_DEG,
    MAX_DEPTH,
    MIN_DEPTH,
    ROBOT_RADIUS,
)

#: Channels of the egocentric feature tensor, in order.
FEATURE_NAMES: tuple[str, ...] = (
    "phi",  # potential rescaled to [0, 1] per map
    "psi",  # log conformal factor
    "travel",  # geodesic distance T / travel_clip, clipped to 1 (1 = unreachable / off-map)
    "grad_forward",  # unit upwind gradient of T, robot-frame forward component
    "grad_left",  # ... left component
    "occupied",
    "explored",
    "goal",  # mean goal likelihood of the points seen in the cell
    "frontier",
)


@dataclass
class GRFieldConfig:
    """Geometry of the sensor and the map, and the physics constants of the field."""

    map_size: int = 192  # cells per side of the allocentric map, centred on the episode start
    cell_size: float = 0.15  # metres per cell
    hfov_deg: float = HFOV_DEG
    camera_height: float = CAMERA_HEIGHT
    camera_forward_offset: float = 0.0
    min_depth: float = MIN_DEPTH
    max_depth: float = MAX_DEPTH
    floor_height: float = 0.1  # points below are floor
    robot_height: float = 1.2  # points above are ignored for occupancy
    robot_radius: float = ROBOT_RADIUS
    goal_threshold: float = 0.5  # mean likelihood for a cell to count as goal
    G: float = 1.0
    goal_mass: float = 1.0
    frontier_mass: float = 1.0
    frontier_mass_goal_seen: float = 0.1
    frontier_min_distance: float = 0.6  # frontier cells nearer the robot are ignored (m)
    obstacle_density: float = 0.05  # mass per square metre of occupied cell (repulsive)
    beta: float = 1.0  # weight of the potential in psi
    kappa: float = 2.0  # weight of obstacle proximity in psi
    obstacle_length: float = 0.3  # decay length (m) of the obstacle term
    unknown_cost: float = 2.0  # extra cost factor of unexplored cells (optimistic planning)
    ego_size: int = 64  # egocentric feature map side (cells)
    ego_cell_size: float | None = None  # defaults to cell_size
    num_waypoints: int = 8
    waypoint_spacing: float = 0.5  # metres between consecutive waypoints
    path_step: float = 0.5  # descent step in cells
    travel_clip: float = 20.0
    planning_margin: float = 3.0  # fast marching runs on the explored bounding box + this (m)
    # sub-cells per cell side where obstacle points are also counted: whether the robot's
    # centre fits in a cell is judged at cell_size / clearance_factor (1: at the cells
    # themselves); a gap a few cells wide is then not closed by where its edges fall in cells
    clearance_factor: int = 1
    # with clearance_factor > 1: room (m) the robot's centre must also keep from the obstacle
    # points on sub-cells (the follower drives near the cells' centres, not the sub-cell's)
    clearance_margin: float = 0.0

    def __post_init__(self) -> None:
        for key in ("map_size", "ego_size", "num_waypoints", "clearance_factor"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"gr_field.{key}={getattr(self, key)} must be >= 1")
        if self.map_size < 3:
            raise ValueError(f"gr_field.map_size={self.map_size} must be >= 3")
        for key in (
            "cell_size", "camera_height", "max_depth", "robot_height", "G", "obstacle_length",
            "unknown_cost", "waypoint_spacing", "path_step", "travel_clip",
        ):  # fmt: skip
            if not getattr(self, key) > 0:
                raise ValueError(f"gr_field.{key}={getattr(self, key)} must be > 0")
        if not 0.0 < self.hfov_deg < 180.0:
            raise ValueError(f"gr_field.hfov_deg={self.hfov_deg} must be in (0, 180)")
        if not 0.0 <= self.min_depth < self.max_depth:
            raise ValueError(f"gr_field.min_depth={self.min_depth} must be in [0, max_depth)")
        if not self.floor_height < self.robot_height:
            raise ValueError(f"gr_field.floor_height={self.floor_height} must be < robot_height")
        if not 0.0 < self.goal_threshold <= 1.0:
            raise ValueError(f"gr_field.goal_threshold={self.goal_threshold} must be in (0, 1]")
        if not 0.0 < self.path_step <= 1.0:
            raise ValueError(f"gr_field.path_step={self.path_step} must be in (0, 1]")
        for key in (
            "goal_mass", "frontier_mass", "frontier_mass_goal_seen", "obstacle_density",
            "beta", "kappa", "robot_radius", "frontier_min_distance", "planning_margin",
            "clearance_margin",
        ):  # fmt: skip
            if getattr(self, key) < 0:
                raise ValueError(f"gr_field.{key}={getattr(self, key)} must be >= 0")
        if self.ego_cell_size is not None and self.ego_cell_size <= 0:
            raise ValueError(f"gr_field.ego_cell_size={self.ego_cell_size} must be > 0")
