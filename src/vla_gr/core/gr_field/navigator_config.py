"""The settings of S2's behaviour (:class:`NavigatorConfig`, ``model.navigator.*``).

The navigator (:mod:`vla_gr.core.gr_field.navigator`) reads them; the GR field it plans on has
its own (:class:`vla_gr.core.gr_field.config.GRFieldConfig`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["NavigatorConfig"]


@dataclass
class NavigatorConfig:
    """Thresholds of the S2 behaviour (metres, radians, ticks); the field has its own config."""

    look_around_angle: float = 2.0 * math.pi  # turned in place at the start
    # finish the turn even when a goal is confirmed during it (no STOP before): the goal's
    # votes and checks see the whole turn first; False ends the turn at a confirmed goal
    look_around_completes: bool = False
    turn_rate: float = 1.0  # fraction of the max angular speed for open-loop turns
    pixel_threshold: float = 0.5  # goal likelihood for a pixel to vote for its cell
    # the goal head's per-frame "goal visible" probability below which a tick casts no goal
    # votes (its pixels still feed the field's mean likelihood); 0 = pixels alone decide
    visible_threshold: float = 0.0
    # approach-and-verify: the "goal visible" probability a STOP needs at the goal; a goal
    # that does not reach it within verify_steps is rejected (0 = off: goal pixels suffice)
    stop_visible_threshold: float = 0.0
    # room instructions: near a confirmed goal, reject it when the mean probability over the
    # last room_ticks ticks that the robot is in a room of the instructed type is below this
    room_reject_threshold: float = 0.0  # 0 = off
    room_ticks: int = 3
    # every goal: near a confirmed goal, reject it when the mean probability, over the last
    # object_ticks ticks that saw goal pixels, that those pixels show an object of the
    # instructed category is below this
    object_reject_threshold: float = 0.0  # 0 = off
    object_ticks: int = 3
    # relation instructions ("the chair near the plant"): the anchor's pixels vote for map
    # cells like goal pixels do; near a confirmed goal, reject it when no anchor cell (votes on
    # anchor_ticks ticks) lies within this distance of the goal's cells
    relation_distance: float = 0.0  # m; 0 = off
    # an anchor cell also needs more ticks with anchor pixels than with goal pixels
    anchor_outvotes_goal: bool = False
    # a goal cell needs at least as many ticks with goal pixels as with anchor pixels
    goal_yields_to_anchor: bool = False
    anchor_ticks: int = 0  # ticks with anchor pixels before a cell is an anchor (0: confirm_ticks)
    confirm_ticks: int = 2  # ticks with goal votes before a cell is a goal
    min_goal_pixels: int = 3  # goal pixels for "the goal is in view now"
    stop_distance: float = 0.8  # m from the robot centre to a confirmed goal cell
    # at the end of the path (a goal in a corner: the stand-off is no nearer) this is enough
    stop_distance_at_end: float = 0.9  # m
    path_end_distance: float = 0.3  # m: the last waypoint this close means the path ends here
    goal_halo_cells: int = 2  # occupied cells this close to goal cells do not block the view
    verify_steps: int = 12  # turning towards the goal before stopping anyway
    # at the end of the path to a goal it cannot stop at this long: reject the goal (0 = off)
    dead_end_steps: int = 30  # val 120-319: with trap_recoveries, SR 0.585 -> 0.600
    # a confirmed goal the field has found no way to for this long on end (planning thinner
    # included): reject it, so that a false goal seen far off (through a door, on a wall)
    # neither holds the robot in thin, half-speed planning nor pulls at it all episode (0 = off)
    unreachable_steps: int = 0
    blocked_steps: int = 15  # window of the blocked test (driving ahead, not moving)
    blocked_distance: float = 0.1  # m
    drive_bearing: float = math.radians(50.0)  # pursuit point within this: the plan drives
    pursuit_lookahead: float = 0.6  # m, the follower's lookahead (for the drive test)
    stuck_steps: int = 100  # window of the no-progress test
    stuck_distance: float = 0.3  # m moved within the window below which the robot is stuck
    recover_back_steps: int = 3  # backing up
    recover_turn_steps: int = 6  # turning after backing up
    recover_back_speed: float = 0.4  # fraction of the max linear speed, backwards
    virtual_obstacle_distance: float = 0.3  # m ahead of the robot centre
    virtual_obstacle_radius: float = 0.08  # m
    virtual_obstacle_hits: float = 100.0  # evidence count (outvotes later free evidence)
    no_path_steps: int = 8  # without a path before a recovery
    # a path must be held this long to reset that count: a path that comes and goes tick by
    # tick as the map changes view by view does not (1: any path resets it)
    path_hold_steps: int = 1
    # recoveries within trap_radius of one another before the robot gives up what it heads
    # for: a committed goal is rejected (with trap_rejects_goal), else the way ahead is closed
    # for good (0 = off)
    trap_recoveries: int = 4
    trap_rejects_goal: bool = True
    trap_radius: float = 0.5  # m
    trap_obstacle_radius: float = 0.25  # m, the lasting obstacle ahead of a trapped robot
    # no path even without virtual obstacles: plan for a thinner robot for a while (passages
    # the conservative inflation closes on a coarse map; the depth check still guards)
    tight_radius: float = 0.05  # m
    tight_steps: int = 150
    tight_speed: float = 0.5  # cap of the linear fraction while planning for a thinner robot
    # unseen cells this close to where the robot stands count as explored: frontiers in the
    # camera's blind spots (under furniture, beside the base) cannot pull it back and forth
    visited_clear_radius: float = 0.8  # m
    # obstacle cells with at most noise_max_hits points but noise_free_ratio times as many
    # free-space hits are mapping noise (grazing points of a door jamb): forgotten, so that
    # one stray point never closes a door for good
    noise_max_hits: float = 2.0
    noise_free_ratio: float = 4.0
    # while planning thin: re-plan the way out at the real radius on fine cells of the depth
    # points (:mod:`vla_gr.core.gr_field.local_planner`); the follower then keeps closer to
    # the path and lets the robot's width (without side margin) through
    local_planner: bool = False
    local_cell: float = 0.025  # m, fine cell side (a whole fraction of the field's cell)
    local_window: float = 1.5  # m, half side of the fine window around the robot
    local_margin: float = 0.02  # m the robot's edge keeps from obstacle points
    local_start_radius: float = 0.1  # m around the robot that is free whatever its clearance
    local_clearance_cost: float = 2.0  # extra cost per metre at the clearance limit
    local_min_progress: float = 0.3  # m nearer in the field's travel time, else no local plan
    local_replan_ticks: int = 3  # ticks a local path is followed before it is planned anew
    local_off_path: float = 0.15  # m off the local path: plan anew at once
    # depth points a fine cell needs before it is an obstacle: a lone noisy point then
    # narrows no gap, while a real surface is seen again frame after frame
    local_min_hits: int = 1

    def __post_init__(self) -> None:
        for key in ("look_around_angle", "stop_distance", "stuck_distance", "blocked_distance",
                    "stop_distance_at_end", "path_end_distance",
                    "virtual_obstacle_radius", "virtual_obstacle_hits",
                    "visited_clear_radius", "tight_radius", "trap_radius",
                    "trap_obstacle_radius", "relation_distance", "local_margin",
                    "local_start_radius", "local_clearance_cost",
                    "local_min_progress", "local_off_path"):  # fmt: skip
            if not getattr(self, key) >= 0:
                raise ValueError(f"model.navigator.{key}={getattr(self, key)} must be >= 0")
        for key in ("confirm_ticks", "min_goal_pixels", "verify_steps", "stuck_steps",
                    "blocked_steps", "no_path_steps", "path_hold_steps", "tight_steps",
                    "room_ticks", "object_ticks", "local_replan_ticks",
                    "local_min_hits"):  # fmt: skip
            if int(getattr(self, key)) < 1:
                raise ValueError(f"model.navigator.{key}={getattr(self, key)} must be >= 1")
        for key in ("recover_back_steps", "recover_turn_steps", "dead_end_steps",
                    "unreachable_steps",
                    "trap_recoveries", "anchor_ticks"):  # fmt: skip
            if int(getattr(self, key)) < 0:
                raise ValueError(f"model.navigator.{key}={getattr(self, key)} must be >= 0")
        for key in ("local_cell", "local_window"):
            if not getattr(self, key) > 0:
                raise ValueError(f"model.navigator.{key}={getattr(self, key)} must be > 0")
        for key in ("turn_rate", "recover_back_speed", "pixel_threshold", "tight_speed"):
            if not 0.0 < getattr(self, key) <= 1.0:
                raise ValueError(f"model.navigator.{key}={getattr(self, key)} must be in (0, 1]")
        for key in ("visible_threshold", "stop_visible_threshold", "room_reject_threshold",
                    "object_reject_threshold"):  # fmt: skip
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise ValueError(f"model.navigator.{key}={getattr(self, key)} must be in [0, 1]")
