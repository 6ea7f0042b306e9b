"""The settings of S2's behaviour (:class:`NavigatorConfig`, ``model.navigator.*``), one section
per concern.

The navigator (:mod:`vla_gr.agent.navigator.navigator`) reads its own settings and hands each
collaborator its section only: :class:`~vla_gr.agent.navigator.goal_checks.GoalChecks` gets
``goal_checks``, :class:`~vla_gr.agent.navigator.local_planner.LocalPlanner` ``local_planner``,
:class:`~vla_gr.agent.navigator.map_edits.MapEdits` ``map_edits``. The GR field it plans on has
its own config (:class:`vla_gr.core.gr_field.config.GRFieldConfig`); the follower's lookahead,
which its drive test uses, is ``model.pursuit.lookahead`` (handed to the navigator).

Sections (``model.navigator.<section>.<key>``): ``look_around`` (the turn at the start),
``confirmation`` (goal pixels -> votes -> a confirmed goal), ``goal_checks`` (room, category,
relation), ``approach`` (stop, verify, give a goal up), ``recovery`` (blocked, stuck, no path),
``traps`` (the same spot again and again), ``tight`` (planning for a thinner robot),
``local_planner`` (fine cells while planning thin), ``map_edits`` (the navigator's own marks
on the map), ``not_found`` (the reachable house searched: declare the object not found),
``room_search`` (frontiers in rooms likely to hold the goal first).
``turn_rate`` is the navigator's own: every open-loop turn uses it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = [
    "ApproachConfig",
    "ConfirmationConfig",
    "GoalChecksConfig",
    "LocalPlannerConfig",
    "LookAroundConfig",
    "MapEditsConfig",
    "NavigatorConfig",
    "NotFoundConfig",
    "RecoveryConfig",
    "RoomSearchConfig",
    "TightConfig",
    "TrapsConfig",
]

_KEY = "model.navigator"

#: (rule as the message says it, test) per kind of range.
_RULES: dict[str, tuple[str, Callable[[object], bool]]] = {
    ">= 0": (">= 0", lambda v: v >= 0),
    "int >= 0": (">= 0", lambda v: int(v) >= 0),
    "int >= 1": (">= 1", lambda v: int(v) >= 1),
    "> 0": ("> 0", lambda v: v > 0),
    "(0, 1]": ("in (0, 1]", lambda v: 0.0 < v <= 1.0),
    "[0, 1]": ("in [0, 1]", lambda v: 0.0 <= v <= 1.0),
}


def _check(config, section: str, rules: dict[str, tuple[str, ...]]) -> None:
    """ValueError naming ``model.navigator.<section>.<key>`` for the first value of ``config``
    outside its range (``rules``: range -> keys)."""
    for rule, keys in rules.items():
        text, test = _RULES[rule]
        for key in keys:
            value = getattr(config, key)
            if not test(value):
                raise ValueError(f"{_KEY}.{section}.{key}={value} must be {text}")


@dataclass
class LookAroundConfig:
    """The turn in place at the start (``model.navigator.look_around``)."""

    angle: float = 2.0 * math.pi  # turned in place at the start
    # finish the turn even when a goal is confirmed during it (no STOP before): the goal's
    # votes and checks see the whole turn first; False ends the turn at a confirmed goal
    completes: bool = False

    def __post_init__(self) -> None:
        _check(self, "look_around", {">= 0": ("angle",)})


@dataclass
class ConfirmationConfig:
    """Goal pixels -> votes on map cells -> a confirmed goal (``model.navigator.confirmation``)."""

    pixel_threshold: float = 0.5  # goal likelihood for a pixel to vote for its cell
    # the goal head's per-frame "goal visible" probability below which a tick casts no goal
    # votes (its pixels still feed the field's mean likelihood); 0 = pixels alone decide
    visible_threshold: float = 0.0
    ticks: int = 2  # ticks with goal votes before a cell is a goal
    min_goal_pixels: int = 3  # goal pixels for "the goal is in view now"

    def __post_init__(self) -> None:
        _check(self, "confirmation", {
            "int >= 1": ("ticks", "min_goal_pixels"),
            "(0, 1]": ("pixel_threshold",),
            "[0, 1]": ("visible_threshold",),
        })  # fmt: skip


@dataclass
class GoalChecksConfig:
    """Checks of a confirmed goal near the robot (``model.navigator.goal_checks``; read by
    :class:`~vla_gr.agent.navigator.goal_checks.GoalChecks`)."""

    # room instructions: near a confirmed goal, reject it when the mean probability over the
    # last room_ticks ticks that the robot is in a room of the instructed type is below this
    room_reject_threshold: float = 0.0  # 0 = off
    room_ticks: int = 3
    # ... unless the room map (room_search: every tick that typed the robot's cell, not only the
    # last few) gives the instructed type at least this probability there; 0 = off
    room_map_keep: float = 0.0
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
    # ticks with anchor pixels before a cell is an anchor (0: confirmation.ticks)
    anchor_ticks: int = 0

    def __post_init__(self) -> None:
        _check(self, "goal_checks", {
            ">= 0": ("relation_distance",),
            "int >= 1": ("room_ticks", "object_ticks"),
            "int >= 0": ("anchor_ticks",),
            "[0, 1]": ("room_reject_threshold", "room_map_keep", "object_reject_threshold"),
        })  # fmt: skip


@dataclass
class ApproachConfig:
    """Approach a confirmed goal, verify it, stop, or give it up (``model.navigator.approach``)."""

    stop_distance: float = 0.8  # m from the robot centre to a confirmed goal cell
    # at the end of the path (a goal in a corner: the stand-off is no nearer) this is enough
    stop_distance_at_end: float = 0.9  # m
    path_end_distance: float = 0.3  # m: the last waypoint this close means the path ends here
    goal_halo_cells: int = 2  # occupied cells this close to goal cells do not block the view
    # approach-and-verify: the "goal visible" probability a STOP needs at the goal; a goal
    # that does not reach it within verify_steps is rejected (0 = off: goal pixels suffice)
    stop_visible_threshold: float = 0.0
    verify_steps: int = 12  # turning towards the goal before stopping anyway
    # at the end of the path to a goal it cannot stop at this long: reject the goal (0 = off)
    dead_end_steps: int = 30  # control steps stuck at the end of the path before rejecting
    # a confirmed goal the field has found no way to for this long on end (planning thinner
    # included): reject it, so that a false goal seen far off (through a door, on a wall)
    # neither holds the robot in thin, half-speed planning nor pulls at it all episode (0 = off)
    unreachable_steps: int = 0

    def __post_init__(self) -> None:
        _check(self, "approach", {
            ">= 0": ("stop_distance", "stop_distance_at_end", "path_end_distance"),
            "int >= 1": ("verify_steps",),
            "int >= 0": ("dead_end_steps", "unreachable_steps"),
            "[0, 1]": ("stop_visible_threshold",),
        })  # fmt: skip


@dataclass
class RecoveryConfig:
    """Blocked, stuck or without a path: back up, turn, re-plan (``model.navigator.recovery``)."""

    blocked_steps: int = 15  # window of the blocked test (driving ahead, not moving)
    blocked_distance: float = 0.1  # m
    # the follower's pursuit point (at model.pursuit.lookahead) within this: the plan drives
    drive_bearing: float = math.radians(50.0)
    stuck_steps: int = 100  # window of the no-progress test
    stuck_distance: float = 0.3  # m moved within the window below which the robot is stuck
    back_steps: int = 3  # backing up
    turn_steps: int = 6  # turning after backing up
    back_speed: float = 0.4  # fraction of the max linear speed, backwards
    virtual_obstacle_distance: float = 0.3  # m ahead of the robot centre
    virtual_obstacle_radius: float = 0.08  # m
    no_path_steps: int = 8  # without a path before a recovery
    # a path must be held this long to reset that count: a path that comes and goes tick by
    # tick as the map changes view by view does not (1: any path resets it)
    path_hold_steps: int = 1

    def __post_init__(self) -> None:
        _check(self, "recovery", {
            ">= 0": ("blocked_distance", "stuck_distance", "virtual_obstacle_radius"),
            "int >= 1": ("blocked_steps", "stuck_steps", "no_path_steps", "path_hold_steps"),
            "int >= 0": ("back_steps", "turn_steps"),
            "(0, 1]": ("back_speed",),
        })  # fmt: skip


@dataclass
class TrapsConfig:
    """Recoveries at one spot again and again (``model.navigator.traps``)."""

    # recoveries within radius of one another before the robot gives up what it heads for: a
    # committed goal is rejected (with rejects_goal), else the way ahead is closed for good
    # (0 = off)
    recoveries: int = 4
    rejects_goal: bool = True
    radius: float = 0.5  # m
    obstacle_radius: float = 0.25  # m, the lasting obstacle ahead of a trapped robot

    def __post_init__(self) -> None:
        _check(self, "traps", {">= 0": ("radius", "obstacle_radius"), "int >= 0": ("recoveries",)})


@dataclass
class TightConfig:
    """No path even without virtual obstacles: plan for a thinner robot for a while
    (``model.navigator.tight``): passages the conservative inflation closes on a coarse map;
    the depth check still guards."""

    radius: float = 0.05  # m
    steps: int = 150
    speed: float = 0.5  # cap of the linear fraction while planning for a thinner robot

    def __post_init__(self) -> None:
        _check(self, "tight", {">= 0": ("radius",), "int >= 1": ("steps",), "(0, 1]": ("speed",)})


@dataclass
class LocalPlannerConfig:
    """While planning thin: re-plan the way out at the real radius on fine cells of the depth
    points (``model.navigator.local_planner``; read by
    :class:`~vla_gr.agent.navigator.local_planner.LocalPlanner`); the follower then keeps closer
    to the path and lets the robot's width (without side margin) through."""

    enabled: bool = False
    cell: float = 0.025  # m, fine cell side (a whole fraction of the field's cell)
    window: float = 1.5  # m, half side of the fine window around the robot
    margin: float = 0.02  # m the robot's edge keeps from obstacle points
    start_radius: float = 0.1  # m around the robot that is free whatever its clearance
    clearance_cost: float = 2.0  # extra cost per metre at the clearance limit
    min_progress: float = 0.3  # m nearer in the field's travel time, else no local plan
    replan_ticks: int = 3  # ticks a local path is followed before it is planned anew
    off_path: float = 0.15  # m off the local path: plan anew at once
    # depth points a fine cell needs before it is an obstacle: a lone noisy point then
    # narrows no gap, while a real surface is seen again frame after frame
    min_hits: int = 1

    def __post_init__(self) -> None:
        _check(self, "local_planner", {
            ">= 0": ("margin", "start_radius", "clearance_cost", "min_progress", "off_path"),
            "int >= 1": ("replan_ticks", "min_hits"),
            "> 0": ("cell", "window"),
        })  # fmt: skip


@dataclass
class MapEditsConfig:
    """The navigator's own marks on its map (``model.navigator.map_edits``; read by
    :class:`~vla_gr.agent.navigator.map_edits.MapEdits`)."""

    obstacle_hits: float = 100.0  # evidence count of a marked obstacle (outvotes later free)
    # obstacle cells with at most noise_max_hits points but noise_free_ratio times as many
    # free-space hits are mapping noise (grazing points of a door jamb): forgotten, so that
    # one stray point never closes a door for good
    noise_max_hits: float = 2.0
    noise_free_ratio: float = 4.0
    # unseen cells this close to where the robot stands count as explored: frontiers in the
    # camera's blind spots (under furniture, beside the base) cannot pull it back and forth
    visited_clear_radius: float = 0.8  # m

    def __post_init__(self) -> None:
        _check(self, "map_edits", {">= 0": ("obstacle_hits", "visited_clear_radius")})


@dataclass
class NotFoundConfig:
    """Declare the object not found when the agent's own map says the reachable house is
    searched (``model.navigator.not_found``): no confirmed goal (none seen, or every one
    rejected by its checks), no way to any frontier at the robot's own radius and (almost)
    nothing newly seen, on end."""

    # control steps on end without a confirmed goal or a way to a frontier at the robot's own
    # radius (look-around aside; a way only planning thinner finds does not count) before
    # declaring "not found": more than a whole stint of planning thinner (tight.steps), so the
    # ways out of a false dead end (forgetting virtual obstacles, planning thinner, recoveries)
    # are tried in full first (0 = never declare)
    steps: int = 180
    # m2 the map may grow by while those steps run; more starts them again (planning thinner
    # got the robot through a narrow passage into house it had not seen)
    new_area: float = 2.0
    # the first time the house counts as searched with goals rejected, forget where they were
    # (their cells vote again) and search on instead of declaring: a right goal rejected with
    # the wrong one beside it (a chair at the table the goal head also lit) gets a second look
    second_look: bool = False

    def __post_init__(self) -> None:
        _check(self, "not_found", {"int >= 0": ("steps",), ">= 0": ("new_area",)})


@dataclass
class RoomSearchConfig:
    """Explore where the goal is likely first (``model.navigator.room_search``,
    :mod:`vla_gr.agent.navigator.room_search`): the map remembers which type of room each
    place the robot passed is (the room-type classifier, every tick), and a frontier in a
    room unlikely to hold the goal is searched after the others. How likely a room type is
    to hold a category is learned from the training houses
    (:mod:`vla_gr.training.room_prior`), never written by hand."""

    enabled: bool = False
    # cells within this distance of the robot, through free seen space, take the type of the
    # room it stands in this tick
    radius: float = 1.5  # m
    # frontier cells valued below keep x the best frontier's value are searched only when no
    # better one can be reached
    keep: float = 0.5
    # the learned tables: per category (a row), P(a room of each type holds one) (a column
    # per room type); the share of each room type among the training houses' rooms
    categories: list[str] = field(default_factory=list)
    room_types: list[str] = field(default_factory=list)
    presence: list[list[float]] = field(default_factory=list)
    room_share: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        _check(self, "room_search", {"> 0": ("radius",), "[0, 1]": ("keep",)})
        rooms = len(self.room_types)
        rows = len(self.presence) == len(self.categories)
        if not rows or len(self.room_share) != rooms or any(len(v) != rooms for v in self.presence):
            raise ValueError(
                f"{_KEY}.room_search: presence needs a row per category "
                f"({len(self.categories)}), room_share and every row a value per room type "
                f"({rooms}: {list(self.room_types)})"
            )
        if self.enabled and not self.presence:
            raise ValueError(
                f"{_KEY}.room_search.enabled needs the learned presence table: "
                "python -m vla_gr.training.room_prior CHECKPOINT OUT"
            )


@dataclass
class NavigatorConfig:
    """S2's behaviour (metres, radians, control steps), one section per concern; the field
    has its own config."""

    turn_rate: float = 1.0  # fraction of the max angular speed for open-loop turns
    look_around: LookAroundConfig = field(default_factory=LookAroundConfig)
    confirmation: ConfirmationConfig = field(default_factory=ConfirmationConfig)
    goal_checks: GoalChecksConfig = field(default_factory=GoalChecksConfig)
    approach: ApproachConfig = field(default_factory=ApproachConfig)
    recovery: RecoveryConfig = field(default_factory=RecoveryConfig)
    traps: TrapsConfig = field(default_factory=TrapsConfig)
    tight: TightConfig = field(default_factory=TightConfig)
    local_planner: LocalPlannerConfig = field(default_factory=LocalPlannerConfig)
    map_edits: MapEditsConfig = field(default_factory=MapEditsConfig)
    not_found: NotFoundConfig = field(default_factory=NotFoundConfig)
    room_search: RoomSearchConfig = field(default_factory=RoomSearchConfig)

    def __post_init__(self) -> None:
        if not 0.0 < self.turn_rate <= 1.0:
            raise ValueError(f"{_KEY}.turn_rate={self.turn_rate} must be in (0, 1]")
        steps, thin = self.not_found.steps, self.tight.steps
        if steps and steps <= thin:  # a stint of thinner planning alone would declare
            raise ValueError(
                f"{_KEY}.not_found.steps={steps} must be 0 or more than {_KEY}.tight.steps={thin}"
            )
