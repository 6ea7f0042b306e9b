"""What one GR field update gives: its allocentric maps, typed (:class:`FieldMaps`), and the
planner's output of the tick (:class:`GRFieldOutput`).

:meth:`vla_gr.core.gr_field.planning.GRField.update` builds one per tick and
:attr:`GRField.maps <vla_gr.core.gr_field.planning.GRField.maps>` exposes the last one. Every
layer lies in the map grid (rows along +y, cols along +x, the grid's lower-left corner at
metric (0, 0)). Readers only read: the map itself is edited through ``GRField``'s methods.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import torch

from vla_gr.core.gr_field.physics import conformal_log_factor, solve_poisson

__all__ = ["FieldMaps", "GRFieldOutput"]


@dataclass(frozen=True, eq=False)
class FieldMaps:
    """Allocentric layers of one update of a batch of B maps of H x W cells.

    ``phi_hat``, the full potential of the update's density ``rho`` rescaled to [0, 1], is
    solved on first read and then kept, so readers that never look at it (the navigator)
    never pay for the Poisson solve.
    """

    psi: torch.Tensor  # (B, H, W) float, log conformal factor of the metric
    travel: torch.Tensor  # (B, H, W) float, geodesic distance T (inf where unreachable)
    occupied: torch.Tensor  # (B, H, W) bool
    explored: torch.Tensor  # (B, H, W) bool
    frontier: torch.Tensor  # (B, H, W) bool
    goal: torch.Tensor  # (B, H, W) bool, goal cells (after the update's goal gate)
    robot_xy: torch.Tensor  # (B, 2) metres from the grid's lower-left corner
    yaw: torch.Tensor  # (B,) radians
    has_path: torch.Tensor  # (B,) bool
    rho: torch.Tensor = field(repr=False)  # (B, H, W) all mass (attracting - obstacles)
    cell_size: float = field(repr=False)  # metres per cell
    G: float = field(repr=False)  # gravitational constant of the Poisson solve

    def __post_init__(self) -> None:
        grid = tuple(self.psi.shape)
        if len(grid) != 3:
            raise ValueError(f"FieldMaps.psi must be (B, H, W), got {grid}")
        for name in ("travel", "occupied", "explored", "frontier", "goal", "rho"):
            if tuple(getattr(self, name).shape) != grid:
                shape = tuple(getattr(self, name).shape)
                raise ValueError(f"FieldMaps.{name} must be (B, H, W)={grid}, got {shape}")
        B = grid[0]
        for name, shape in (("robot_xy", (B, 2)), ("yaw", (B,)), ("has_path", (B,))):
            if tuple(getattr(self, name).shape) != shape:
                got = tuple(getattr(self, name).shape)
                raise ValueError(f"FieldMaps.{name} must be {shape}, got {got}")

    @cached_property
    def phi_hat(self) -> torch.Tensor:
        """(B, H, W) potential of ``rho`` rescaled to [0, 1] per map; solved once, on first read."""
        phi = solve_poisson(self.rho, self.cell_size, self.G)  # (B, H, W)
        return conformal_log_factor(phi, torch.zeros_like(phi), 1.0, 0.0)  # (B, H, W)


@dataclass
class GRFieldOutput:
    """What one planner tick produces.

    ``features`` are computed from this tick's maps on first access and then kept: a planner
    that only follows the waypoints (the navigator) never pays for them.
    """

    make_features: Callable[[], torch.Tensor] = field(repr=False)
    waypoints: torch.Tensor  # (B, K, 2) robot frame (forward, left), metres; 0 when no path
    has_path: torch.Tensor  # (B,) bool
    goal_seen: torch.Tensor  # (B,) bool: the path leads to the goal, not to the frontier
    distance: torch.Tensor  # (B,) geodesic distance (metric units) from the robot; inf if none

    @cached_property
    def features(self) -> torch.Tensor:
        """(B, C, h, w) egocentric, heading-aligned, channels ``FEATURE_NAMES``."""
        return self.make_features()
