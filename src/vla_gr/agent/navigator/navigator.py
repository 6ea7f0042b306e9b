"""S2 navigation behaviour on the GR field: look around, explore, approach, verify, recover, stop.

A batch-1 state machine that owns a :class:`~vla_gr.core.gr_field.GRField`. Each planner tick
takes depth, pose and a per-pixel goal likelihood (from whatever grounds the instruction; it
never sees privileged state) and returns a :class:`NavPlan`: waypoints in the robot frame or an
open-loop command, the mode, a goal confidence and a STOP request.

Modes and transitions (checked in this order every tick; settings are named below
``model.navigator``, :mod:`vla_gr.agent.navigator.config`)::

    look_around  turn in place until look_around.angle is covered (or, unless
                 look_around.completes, a goal is confirmed)
    recover      blocked or stuck: (a virtual obstacle ahead,) back up, turn; then re-plan
    stop         a confirmed goal cell within approach.stop_distance (stop_distance_at_end
                 when the path ends here), in line of sight, goal pixels in view now and (with
                 approach.stop_visible_threshold) the goal head's "goal visible" probability
                 this high
    verify       the same but not (yet) verified: turn towards it (approach.verify_steps at
                 most); then stop anyway, or with stop_visible_threshold reject that goal and
                 explore on; a goal that fails a goal check (room, category, relation) is
                 rejected before either
    approach     a confirmed goal: follow the field's geodesic to its stand-off; a goal the
                 robot has stood at the end of the path to for approach.dead_end_steps without
                 being able to stop (not within stop distance in line of sight) is rejected,
                 and so is one the field has found no way to for approach.unreachable_steps
    explore      no confirmed goal: follow the field's geodesic to the frontier

Not found (:mod:`vla_gr.agent.navigator.search`, ``not_found``): a plan says ``not_found`` once
the map has had no confirmed goal, no way to a frontier at the robot's own radius (planning
thinner does not count) and almost no new house for ``steps`` on end: the house is searched.

Multi-frame confirmation: a map cell becomes a goal for the field (``GRField.update``'s
``goal_gate``) only after goal pixels landed in it on ``confirmation.ticks`` different ticks,
so a single false positive never attracts. Approach-and-verify: with
``approach.stop_visible_threshold`` a STOP also needs the goal head's per-frame "goal visible"
probability, seen from close range; a goal that never reaches it within
``approach.verify_steps`` is rejected: its cells lose their votes and cast none again, and the
robot explores on. Goal checks (:mod:`vla_gr.agent.navigator.goal_checks`, ``goal_checks``): near
a confirmed goal, the room the robot stands in, the category the goal pixels show and, for a
relation, an anchor mapped near the goal can reject it the same way. The same happens to a dead
end: a goal whose path ends where the robot stands but which is not in line of sight within the
stop distance (the head fired on something behind furniture or a wall), which would otherwise
hold the robot there until the step budget runs out. Blocked: the plan wanted to drive ahead
(its pursuit point, at the follower's ``lookahead``, within ``recovery.drive_bearing``) on
every tick of the last ``recovery.blocked_steps`` control steps but the robot moved less than
``recovery.blocked_distance`` (Stubborn's collision test): a virtual obstacle is marked in
front (the path then bends around it), the robot backs up and turns. Stuck: less than
``recovery.stuck_distance`` over ``recovery.stuck_steps`` in explore/approach: back up and
turn. No path for ``recovery.no_path_steps`` (a path found in between counts only once held
for ``recovery.path_hold_steps``): the virtual obstacles are forgotten (they may close a door);
if there are none, the field plans for a thinner robot (``tight.radius``, at ``tight.speed``)
for ``tight.steps``; with ``local_planner.enabled`` the way out is then re-planned at the real
radius on fine cells of the depth points (:mod:`vla_gr.agent.navigator.local_planner`) and
followed as a precise plan; after that, back up and turn. Trapped (``traps.recoveries``
recoveries within ``traps.radius`` of one another: planning thinner and forgetting virtual
obstacles keep sending the robot into the same gap): the way ahead is closed for good by an
obstacle that is never forgotten, or, with ``traps.rejects_goal``, a committed goal is
rejected instead.

Map hygiene, every tick: :mod:`vla_gr.agent.navigator.map_edits` (``map_edits``).
Durations are in control steps and become ticks through ``plan_every``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage

from vla_gr.agent.navigator.config import NavigatorConfig
from vla_gr.agent.navigator.goal_checks import GoalChecks
from vla_gr.agent.navigator.local_planner import LocalPlanner
from vla_gr.agent.navigator.map_edits import MapEdits
from vla_gr.agent.navigator.room_search import RoomSearch
from vla_gr.agent.navigator.search import SearchCount
from vla_gr.agent.navigator.sight import nearest_goal_in_sight
from vla_gr.core.gr_field.config import GRFieldConfig
from vla_gr.core.gr_field.mapping import points_to_cells
from vla_gr.core.gr_field.planning import GRField
from vla_gr.geometry.pose2d import lookahead_target, map_to_robot, wrap_angle

logger = logging.getLogger(__name__)

MODES = ("look_around", "explore", "approach", "verify", "recover", "stop")


@dataclass
class NavPlan:
    """One planner tick's output (batch 1)."""

    waypoints: np.ndarray  # (K, 2) robot frame (forward, left) metres; (0, 2) when none
    mode: str  # one of MODES
    goal_confidence: float  # in [0, 1]: evidence for the committed (or best) goal cells
    stop: bool  # STOP request
    command: tuple[float, float] | None = None  # open-loop (v, w) fractions until the next tick
    goal_distance: float = math.inf  # m from the robot to the nearest confirmed goal cell
    max_speed: float = 1.0  # cap of the linear fraction the follower may use
    # a fine local path (navigator.local_planner.enabled): the follower pursues nearer along it and
    # lets the robot's width through without side margin
    precise: bool = False
    # the reachable house is searched without a goal (navigator.not_found): declare not found
    not_found: bool = False


class Navigator:
    """S2 behaviour on a batch-1 GR field (see module docstring).

    Args:
        config: the navigator's settings (``model.navigator``); each collaborator is handed
            its own section (goal checks, local planner, map edits).
        field_config: the GR field's (``model.gr_field``).
        plan_every: control steps per tick (the ``*_steps`` durations become ticks).
        lookahead: metres, the follower's lookahead (``model.pursuit.lookahead``): the drive
            test asks whether the point it pursues lies within ``recovery.drive_bearing``.
    """

    def __init__(
        self,
        config: NavigatorConfig | None = None,
        field_config: GRFieldConfig | None = None,
        plan_every: int = 1,
        *,
        lookahead: float,
    ) -> None:
        if int(plan_every) < 1:
            raise ValueError(f"plan_every={plan_every} must be >= 1 (control steps per tick)")
        if not lookahead > 0:
            raise ValueError(f"lookahead={lookahead} must be > 0 m (model.pursuit.lookahead)")
        self.plan_every = int(plan_every)  # the *_steps durations of the config become ticks
        self.lookahead = float(lookahead)  # the follower's, for the drive test
        self.config = config or NavigatorConfig()
        self.field_config = field_config or GRFieldConfig()
        self.field = GRField(dataclasses.replace(self.field_config))  # its own copy
        self.local = (
            LocalPlanner(
                self.field.grid,
                self.field_config.robot_radius,
                self.config.local_planner,
                self.field_config.floor_height,
                self.field_config.robot_height,
            )  # fmt: skip
            if self.config.local_planner.enabled
            else None
        )  # its fine cells are allocated once and cleared per episode
        self.reset()

    def steps_to_ticks(self, steps: int) -> int:
        """Planner ticks covering ``steps`` control steps (at least 1 for steps > 0)."""
        return math.ceil(steps / self.plan_every) if steps > 0 else 0

    def reset(self) -> None:
        """Start a new episode: empty map, no evidence, look around first."""
        shape = self.field.grid.shape
        self.field.reset()
        self.goal_votes = np.zeros(shape, np.int32)  # (H, W) ticks with goal pixels per cell
        self.rejected = np.zeros(shape, bool)  # (H, W) cells of rejected goals (cast no votes)
        self.rejections = 0
        self.rejection_log: list[dict] = []  # per rejected goal: reason, tick, xy (start frame)
        self.mode = "look_around"
        self.ticks = 0
        self.turned = 0.0
        self.last_yaw: float | None = None
        self.positions: deque[np.ndarray] = deque(
            maxlen=self.steps_to_ticks(self.config.recovery.stuck_steps) + 1
        )  # (2,) per driving tick
        self.drives: deque[tuple[np.ndarray, bool]] = deque(
            maxlen=self.steps_to_ticks(self.config.recovery.blocked_steps) + 1
        )  # ((2,), the plan drove ahead) per driving tick
        self.map_edits = MapEdits(
            self.field, self.config.map_edits
        )  # virtual obstacles, noise, visited
        self.field.set_planning_radius(self.field_config.robot_radius)
        self._radius = self.field_config.robot_radius  # the planning radius outside tight mode
        self.tight_left = 0
        self.unreachable_count = 0  # ticks without a way to the goal, since tight planning
        self.out_of_reach = 0  # ticks on end without a way to the committed goal
        self.recover_left = 0
        self.verify_count = 0
        self.dead_end_count = 0
        self.no_path_count = 0
        self.path_streak = 0  # consecutive driving ticks with a path
        self.recoveries = 0
        self.recovery_spots: list[np.ndarray] = []  # (2,) where recent recoveries started
        self.traps = 0
        self.committed = False
        self.ever_seen_goal = False
        self.tick_goal_pixels = 0  # goal pixels of this tick that landed on the map
        self.stop_evidence: dict[str, float] = {}  # what S2 saw on the tick it asked to STOP
        self.room_belief: float | None = None  # RoomSearch.room_belief at the robot, this tick
        self.checks = GoalChecks(
            self.config.goal_checks, self.config.confirmation.ticks, shape, self.field.cell_size
        )
        self.search = SearchCount(
            self.config.not_found, self.steps_to_ticks(self.config.not_found.steps)
        )  # is the reachable house searched?
        self.room_search = (
            RoomSearch(self.config.room_search, shape, self.field.cell_size)
            if self.config.room_search.enabled
            else None
        )  # which rooms the robot passed; set_search_goal() says what it looks for
        if self.local is not None:
            self.local.reset()
        self._tick_frame, self._projected = None, None  # this tick's depth, pose; their cells
        self.last_output = None
        self.last_latency = 0.0

    def set_search_goal(self, category: str | None, room: str | None) -> None:
        """This episode's goal category and room as read (class names; None: not named), for
        ``room_search``: frontiers in rooms likely to hold it are searched first."""
        if self.room_search is not None:
            self.room_search.set_goal(category, room)

    # ------------------------------------------------------------------ tick

    def plan(
        self,
        obs: dict,
        goal_likelihood,
        goal_visible: float = 1.0,
        room_match: float = 1.0,
        object_match: float | None = None,
        anchor_likelihood=None,
        room_probs=None,
    ) -> NavPlan:
        """One planner tick.

        Args:
            obs: ``depth`` (H, W, 1) or (H, W) metres and ``pose`` (3,) (a leading batch of 1
                is accepted too).
            goal_likelihood: (H, W) per-pixel probability in [0, 1] that the pixel shows the
                instructed object.
            goal_visible: probability that the instructed object is in view at all (the goal
                head's per-frame output); below ``confirmation.visible_threshold`` the tick casts
                no votes.
            room_match: probability that the robot stands in a room of the type the
                instruction names (1 when it names none); see
                ``goal_checks.room_reject_threshold``.
            object_match: probability that this frame's goal pixels show an object of the
                instructed category (None: no evidence this tick); see
                ``goal_checks.object_reject_threshold``.
            anchor_likelihood: (H, W) per-pixel probability of the category a relation
                instruction names as its anchor; None when it names none. See
                ``goal_checks.relation_distance``.
            room_probs: (R,) probabilities of the type of room the robot stands in (the
                room-type classifier's), for ``room_search``; None: no evidence this tick.
        """
        t0 = time.perf_counter()
        cfg = self.config
        depth = torch.as_tensor(np.asarray(obs["depth"], np.float32)).reshape(
            1, *np.shape(goal_likelihood)[-2:]
        )  # (1, H, W)
        pose = torch.as_tensor(np.asarray(obs["pose"], np.float32)).reshape(1, 3)  # (1, 3)
        like = torch.as_tensor(np.asarray(goal_likelihood, np.float32)).reshape(depth.shape)
        votes_allowed = float(goal_visible) >= cfg.confirmation.visible_threshold
        self.checks.observe(room_match, object_match)
        self.tick_goal_pixels = 0  # set by _vote; stays 0 on a tick that casts no votes
        self._tick_frame, self._projected = (depth, pose), None  # projected on demand
        visible = votes_allowed and self._vote(like)  # goal pixels in view now
        if anchor_likelihood is not None:
            anchor = torch.as_tensor(np.asarray(anchor_likelihood, np.float32)).reshape(1, -1)
            self.checks.add_anchor(self._pixel_cells(anchor))  # (M, 2) cells
        confirmed = self.checks.confirmed_goal(self.goal_votes)  # (H, W)
        gate = torch.from_numpy(confirmed)[None]  # (1, H, W)
        if self.tight_left > 0:
            self.tight_left -= 1
            if self.tight_left == 0:
                self.field.set_planning_radius(self._radius)
        thin = self.tight_left > 0  # this tick plans for a thinner robot
        if self.local is not None:
            self.local.observe(*self._project()[2:])
        self.map_edits.mark_visited(pose[0, :2].numpy())
        self.map_edits.forget_noise()
        value = None if self.room_search is None else self.room_search.value()  # (H, W)
        out = self.field.update(
            {"depth": depth, "pose": pose}, like, goal_gate=gate,
            frontier_value=None if value is None else torch.from_numpy(value)[None],
            frontier_keep=cfg.room_search.keep, projection=self._project()[2:],
        )  # fmt: skip
        self.last_output = out
        maps = self.field.maps
        cell = tuple(int(v) for v in self.field.grid.world_to_cell(pose[0, :2].numpy()))
        if self.room_search is not None and room_probs is not None:  # typed for the next tick
            free = (maps.explored[0] & ~maps.occupied[0]).numpy()  # (H, W)
            self.room_search.observe(np.asarray(room_probs), cell, free)
        # the instructed room's, where the robot stands (goal_checks)
        self.room_belief = None if self.room_search is None else self.room_search.room_belief(cell)
        goal_cells = maps.goal[0].numpy()  # (H, W) confirmed goal cells
        self.committed = bool(goal_cells.any())
        robot_xy = maps.robot_xy[0].numpy()  # (2,) from the grid corner
        distance, nearest = nearest_goal_in_sight(
            goal_cells, robot_xy, maps.occupied[0].numpy(), self.field.cell_size,
            self.config.approach.goal_halo_cells,
        )  # fmt: skip
        votes = float(self.goal_votes.max()) if self.goal_votes.any() else 0.0
        confidence = min(1.0, votes / cfg.confirmation.ticks)
        p = pose[0].numpy().astype(np.float64)  # (3,)
        plan = self._decide(out, p, robot_xy, visible, goal_visible, distance, nearest)
        plan.goal_confidence, plan.goal_distance = confidence, distance
        way = self.committed or plan.stop or plan.mode == "look_around"
        way = way or (bool(out.has_path[0]) and not thin)  # a frontier at the robot's own radius
        searched = self.search.update(way, float(maps.explored[0].sum()) * self.field.cell_size**2)
        if searched and self.search.look_again(bool(self.rejected.any())):
            self.rejected[:] = False  # the rejected goals vote again (not_found.second_look)
            searched = False
        plan.not_found = searched
        if plan.stop and not self.stop_evidence:
            self.stop_evidence = self._evidence(goal_cells, goal_visible, like, distance, nearest)
        plan.max_speed = cfg.tight.speed if self.tight_left > 0 else 1.0
        self.mode = plan.mode
        self.ticks += 1
        self.last_latency = time.perf_counter() - t0
        return plan

    def _decide(self, out, pose, robot_xy, visible, goal_visible, distance, nearest) -> NavPlan:
        """The state machine: mode, waypoints / command and STOP for this tick."""
        cfg = self.config
        yaw = float(pose[2])
        if self.last_yaw is not None:
            self.turned += abs(wrap_angle(yaw - self.last_yaw))
        self.last_yaw = yaw

        looking = self.mode == "look_around" and (cfg.look_around.completes or not self.committed)
        if looking and self.turned < cfg.look_around.angle:
            return self._command_plan("look_around", (0.0, cfg.turn_rate))
        rec, app = cfg.recovery, cfg.approach
        if self.recover_left > 0:
            self.recover_left -= 1
            backing = self.recover_left >= self.steps_to_ticks(rec.turn_steps)
            command = (-rec.back_speed, 0.0) if backing else (0.0, cfg.turn_rate)
            return self._command_plan("recover", command)

        at_end = bool(out.has_path[0]) and float(out.waypoints[0, -1].norm()) <= (
            app.path_end_distance
        )
        near = distance <= (app.stop_distance_at_end if at_end else app.stop_distance)
        if self.committed and near:
            failed = self.checks.failed(
                lambda: self._goal_component(nearest), self.goal_votes, self.room_belief
            )
            if failed is not None:
                return self._abandon_goal(nearest, failed)
            verified = float(goal_visible) >= app.stop_visible_threshold
            if visible and verified:
                return NavPlan(np.zeros((0, 2)), "stop", 0.0, True)
            if self.verify_count >= self.steps_to_ticks(app.verify_steps):
                if app.stop_visible_threshold == 0.0:
                    return NavPlan(np.zeros((0, 2)), "stop", 0.0, True)
                return self._abandon_goal(nearest, "verify")
            self.verify_count += 1
            bearing = math.atan2(nearest[1] - robot_xy[1], nearest[0] - robot_xy[0])
            turn = math.copysign(cfg.turn_rate, wrap_angle(bearing - yaw))
            return self._command_plan("verify", (0.0, turn))
        self.verify_count = 0
        self.dead_end_count = self.dead_end_count + 1 if self.committed and at_end else 0
        if app.dead_end_steps and self.dead_end_count >= self.steps_to_ticks(app.dead_end_steps):
            return self._abandon_goal(nearest, "dead_end")

        mode = "approach" if self.committed else "explore"
        self.positions.append(pose[:2].copy())  # progress is judged while driving only
        if self._blocked():
            return self._start_recovery(pose, mark=True, nearest=nearest)
        if self._stuck():
            return self._start_recovery(pose, mark=False, nearest=nearest)
        if not bool(out.has_path[0]):
            self.drives.append((pose[:2].copy(), False))
            self.path_streak = 0
            self.no_path_count += 1
            if self.no_path_count >= self.steps_to_ticks(rec.no_path_steps):
                self.no_path_count = 0
                if self.map_edits.virtual:
                    self.map_edits.clear_virtual_obstacles()
                elif self.tight_left == 0 and cfg.tight.radius < self._radius:
                    self._start_tight()
                else:
                    return self._start_recovery(pose, mark=False, nearest=nearest)
            return self._command_plan(mode, (0.0, cfg.turn_rate))
        self.path_streak += 1
        if self.path_streak >= self.steps_to_ticks(rec.path_hold_steps):
            self.no_path_count = 0
        # a confirmed goal the field cannot reach (it falls back to the frontier): the goal's
        # stand-off may sit in a passage the conservative inflation closes; plan thinner
        unreachable = self.committed and not bool(out.goal_seen[0])
        self.unreachable_count = self.unreachable_count + 1 if unreachable else 0
        self.out_of_reach = self.out_of_reach + 1 if unreachable else 0
        if app.unreachable_steps and self.out_of_reach >= self.steps_to_ticks(
            app.unreachable_steps
        ):
            self.out_of_reach = 0
            return self._abandon_goal(nearest, "unreachable")
        if (
            self.unreachable_count >= self.steps_to_ticks(rec.no_path_steps)
            and self.tight_left == 0
        ):
            self._start_tight()
        waypoints = out.waypoints[0].numpy().astype(np.float64)  # (K, 2)
        local = self._local_path(pose, robot_xy) if self.tight_left > 0 else None
        if local is not None:
            waypoints = local
        target = lookahead_target(waypoints, self.lookahead)  # (2,) robot frame
        ahead = abs(math.atan2(target[1], target[0])) < rec.drive_bearing
        self.drives.append((pose[:2].copy(), bool(ahead and np.hypot(*target) > 0.2)))
        return NavPlan(waypoints, mode, 0.0, False, precise=local is not None)

    # ------------------------------------------------------------------ pieces

    def _reject_goal(self, centre: np.ndarray, reason: str) -> None:
        """Give up the confirmed goal with a cell centred at ``centre`` (2,) (metres from the
        grid corner): its connected cells and their two-cell rim lose their votes for good.
        ``reason`` (a check's name, "verify", "dead_end", "unreachable" or "trap") goes to
        the log."""
        goal = self._goal_component(centre, rim=2)  # (H, W) this goal's cells and rim
        grid = self.field.grid
        xy = np.asarray(centre, np.float64) + (grid.origin_x, grid.origin_y)  # (2,) start frame
        self.rejection_log.append(
            {"reason": reason, "tick": int(self.ticks), "xy": [round(float(v), 3) for v in xy]}
        )
        self.rejected |= goal
        self.goal_votes[goal] = 0
        self.checks.goal_rejected()
        self.committed = False
        self.rejections += 1
        logger.debug("navigator: goal at %s m rejected", np.round(np.asarray(centre), 2))

    def _goal_component(self, centre: np.ndarray, rim: int = 0) -> np.ndarray:
        """Cells (H, W) bool of the confirmed goal with a cell centred at ``centre`` (2,)
        (metres from the grid corner), grown by ``rim`` cells; its 5 x 5 neighbourhood when
        that cell is not (or no longer) a confirmed one."""
        confirmed = self.checks.confirmed_goal(self.goal_votes)  # (H, W)
        grown = ndimage.binary_dilation(confirmed, iterations=rim) if rim else confirmed
        labels, _ = ndimage.label(grown, np.ones((3, 3), bool))
        row, col = (np.asarray(centre) / self.field.cell_size).astype(int)[::-1]
        if labels[row, col]:
            return labels == labels[row, col]
        goal = np.zeros_like(confirmed)
        goal[max(row - 2, 0) : row + 3, max(col - 2, 0) : col + 3] = True
        return goal

    def _abandon_goal(self, nearest: np.ndarray, reason: str) -> NavPlan:
        """Reject the committed goal nearest ``nearest`` (2,) for ``reason``, reset the
        counters that led here (verification, dead end) and turn in place to explore on."""
        self._reject_goal(nearest, reason)
        self.verify_count = 0
        self.dead_end_count = 0
        return self._command_plan("explore", (0.0, self.config.turn_rate))

    def _command_plan(self, mode: str, command: tuple[float, float]) -> NavPlan:
        if mode in ("look_around", "recover", "verify"):
            self.positions.clear()
            self.drives.clear()
        return NavPlan(np.zeros((0, 2)), mode, 0.0, False, command=command)

    def _evidence(
        self, goal_cells: np.ndarray, goal_visible: float, like, distance, nearest
    ) -> dict:
        """The goal evidence behind a STOP: per-frame visible probability, goal pixels and
        peak likelihood now, the votes of the confirmed goal cells, and the checks (room,
        object category, an anchor mapped near the goal; None where they have no input)."""
        votes = self.goal_votes[goal_cells]  # (M,) of the confirmed cells
        return {
            "goal_visible": round(float(goal_visible), 4),
            "goal_pixels": int(self.tick_goal_pixels),
            "peak_likelihood": round(float(like.max()), 4),
            "goal_cells": int(goal_cells.sum()),
            "max_votes": int(votes.max()) if votes.size else 0,
            "total_votes": int(votes.sum()),
            "distance": round(float(distance), 3),
            **self.checks.evidence(
                None if nearest is None else self._goal_component(nearest),
                self.goal_votes,
                self.room_belief,
            ),
            "tick": int(self.ticks),
        }

    def _local_path(self, pose: np.ndarray, robot_xy: np.ndarray) -> np.ndarray | None:
        """The local planner's path (N, 2) in the robot frame, or None (off, or no fine cell
        gets the robot nearer)."""
        if self.local is None:
            return None
        maps = self.field.maps
        path = self.local.follow(
            robot_xy, maps.travel[0].numpy(), maps.occupied[0].numpy()
        )  # (N, 2) from the grid corner
        if path is None:
            return None
        return map_to_robot(path, np.array([*robot_xy, pose[2]]))  # both from the grid corner

    def _project(self):
        """This tick's pixels on the map: (cells (1, N, 2), usable (1, N), points (1, N, 3),
        valid (1, N)), usable = a valid depth reading that lands inside the grid; computed
        once per tick."""
        if self._projected is not None:
            return self._projected
        depth, pose = self._tick_frame  # (1, H, W), (1, 3)
        points, valid = self.field.project(depth, pose)  # (1, N, 3), (1, N)
        cells, inside = points_to_cells(points[..., :2], self.field.grid)  # (1, N, 2), (1, N)
        self._projected = (cells, valid & inside, points, valid)
        return self._projected

    def _pixel_cells(self, probability: torch.Tensor) -> np.ndarray:
        """Distinct cells (M, 2) that this tick's pixels with ``probability`` (1, N) >=
        pixel_threshold land in, outside rejected goals."""
        hits = probability >= self.config.confirmation.pixel_threshold  # (1, N)
        if not bool(hits.any()):
            return np.zeros((0, 2), np.int64)
        cells, usable = self._project()[:2]
        keep = hits & usable  # (1, N)
        rc = np.unique(cells[keep].numpy(), axis=0) if bool(keep.any()) else cells[0, :0].numpy()
        return rc[~self.rejected[rc[:, 0], rc[:, 1]]]

    def _vote(self, like) -> bool:
        """Add one vote to every cell goal pixels (``like`` (1, H, W)) land in this tick; True
        if the goal is in view."""
        hits = (like >= self.config.confirmation.pixel_threshold).reshape(1, -1)  # (1, N)
        if not bool(hits.any()):
            return False
        self.tick_goal_pixels = int((hits & self._project()[1]).sum())
        visible = self.tick_goal_pixels >= self.config.confirmation.min_goal_pixels
        rc = self._pixel_cells(like.reshape(1, -1))  # (M, 2)
        if self.tick_goal_pixels:
            self.goal_votes[rc[:, 0], rc[:, 1]] += 1
            self.ever_seen_goal = True
        return visible

    def _stuck(self) -> bool:
        """Moved less than recovery.stuck_distance over the last recovery.stuck_steps (window
        full)."""
        cfg = self.config.recovery
        if len(self.positions) <= self.steps_to_ticks(cfg.stuck_steps):
            return False
        pts = np.stack(self.positions)  # (T, 2)
        spread = np.linalg.norm(pts - pts[-1], axis=-1).max()
        return bool(spread < cfg.stuck_distance)

    def _start_tight(self) -> None:
        """Plan for a robot of ``tight.radius`` for the next ``tight.steps``."""
        self.unreachable_count = 0
        if self.config.tight.radius < self._radius:
            self.field.set_planning_radius(self.config.tight.radius)
            self.tight_left = self.steps_to_ticks(self.config.tight.steps)

    def _blocked(self) -> bool:
        """The plan drove ahead on every tick of a full window, and the robot barely moved."""
        cfg = self.config.recovery
        if len(self.drives) <= self.steps_to_ticks(cfg.blocked_steps):
            return False
        if not all(drive for _, drive in list(self.drives)[:-1]):
            return False
        pts = np.stack([xy for xy, _ in self.drives])  # (T, 2)
        return bool(np.linalg.norm(pts - pts[-1], axis=-1).max() < cfg.blocked_distance)

    def _start_recovery(self, pose: np.ndarray, mark: bool, nearest=None) -> NavPlan:
        """(Mark a virtual obstacle ahead,) then back up and turn (Stubborn's untrap); when
        trapped, first give up what the robot heads for (see module docstring)."""
        cfg, rec, traps = self.config, self.config.recovery, self.config.traps
        self.recoveries += 1
        if traps.recoveries:
            self.recovery_spots.append(pose[:2].copy())
            spots = np.stack(self.recovery_spots)  # (R, 2)
            if (np.linalg.norm(spots - pose[:2], axis=-1) <= traps.radius).sum() >= (
                traps.recoveries
            ):
                self._give_up(pose, nearest)
        self.positions.clear()
        self.drives.clear()
        if self.local is not None:
            self.local.forget()
        if mark:
            heading = np.array([math.cos(pose[2]), math.sin(pose[2])])
            centre = pose[:2] + rec.virtual_obstacle_distance * heading  # (2,) map frame
            self.map_edits.mark_obstacle(centre, rec.virtual_obstacle_radius)
        self.recover_left = self.steps_to_ticks(rec.back_steps) + self.steps_to_ticks(
            rec.turn_steps
        )
        logger.debug("navigator: stuck at %s, recovery %d", pose, self.recoveries)
        if self.recover_left == 0:
            return self._command_plan("recover", (0.0, 0.0))
        self.recover_left -= 1
        backing = self.recover_left >= self.steps_to_ticks(rec.turn_steps)
        command = (-rec.back_speed, 0.0) if backing else (0.0, cfg.turn_rate)
        return self._command_plan("recover", command)

    def _give_up(self, pose: np.ndarray, nearest) -> None:
        """Trapped: reject the committed goal (``nearest`` (2,), its cell centre from the grid
        corner) with ``traps.rejects_goal``, else close the way ahead for good."""
        self.traps += 1
        self.recovery_spots.clear()
        traps = self.config.traps
        if self.committed and nearest is not None and traps.rejects_goal:
            self._reject_goal(nearest, "trap")
            return
        heading = np.array([math.cos(pose[2]), math.sin(pose[2])])
        ahead = self.config.recovery.virtual_obstacle_distance + traps.obstacle_radius
        self.map_edits.mark_obstacle(
            pose[:2] + ahead * heading, traps.obstacle_radius, lasting=True
        )
        logger.debug("navigator: trapped at %s, the way ahead is closed", pose)
