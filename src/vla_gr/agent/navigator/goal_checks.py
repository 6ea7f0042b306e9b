"""S2's checks of a confirmed goal before a STOP: the room, the object's category, a relation.

The navigator (:mod:`vla_gr.agent.navigator.navigator`) feeds :class:`GoalChecks` on every tick
and asks it, near a confirmed goal, whether the goal must be rejected (settings:
``model.navigator.goal_checks``, :class:`~vla_gr.agent.navigator.config.GoalChecksConfig`):

- room: the mean over the last ``room_ticks`` ticks of the probability that the robot stands
  in a room of the instructed type is below ``room_reject_threshold``, and (with
  ``room_map_keep``) the room map's belief in that type at the robot's cell, from every tick
  that typed it (:meth:`~vla_gr.agent.navigator.room_search.RoomSearch.room_belief`), is below
  ``room_map_keep`` too: a few ticks of a doubtful view do not outweigh all the robot saw there;
- object: the mean over the last ``object_ticks`` ticks with evidence of the probability that
  the goal pixels show the instructed category is below ``object_reject_threshold``;
- relation: no anchor cell (anchor pixels landed in it on ``anchor_ticks`` ticks, by default
  ``confirmation.ticks``; with ``anchor_outvotes_goal`` also on more ticks than
  goal pixels did) lies within ``relation_distance`` of the goal's cells.

A threshold or distance of 0 switches its check off; the STOP evidence records all three.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from vla_gr.agent.navigator.config import GoalChecksConfig

__all__ = ["GoalChecks"]


class GoalChecks:
    """The evidence of the three checks for one episode.

    Args:
        config: the checks' settings (``model.navigator.goal_checks``: thresholds, tick
            windows, the relation's anchor).
        confirm_ticks: ticks with goal pixels before a cell is a goal
            (``model.navigator.confirmation.ticks``); also the anchor's when
            ``config.anchor_ticks`` is 0.
        shape: (H, W) of the navigator's map; ``cell_size`` its cells' side in metres.
    """

    def __init__(
        self,
        config: GoalChecksConfig,
        confirm_ticks: int,
        shape: tuple[int, int],
        cell_size: float,
    ) -> None:
        self.config, self.confirm_ticks = config, confirm_ticks
        self.shape, self.cell_size = shape, float(cell_size)
        self.reset()

    def reset(self) -> None:
        """A new episode: no evidence."""
        self.room_matches: deque[float] = deque(maxlen=self.config.room_ticks)
        self.object_matches: deque[float] = deque(maxlen=self.config.object_ticks)
        self.anchor_votes = np.zeros(self.shape, np.int32)  # (H, W) ticks with anchor pixels
        self.has_anchor = False  # the instruction names a relation's anchor (one was given)
        self.room_map_kept = 0  # ticks the room map kept a goal the last ticks would reject

    def observe(self, room_match: float, object_match: float | None) -> None:
        """One tick's room probability and object probability (None: no evidence)."""
        self.room_matches.append(float(room_match))
        if object_match is not None:
            self.object_matches.append(float(object_match))

    def add_anchor(self, cells: np.ndarray) -> None:
        """One tick's anchor: the distinct cells (M, 2) its pixels landed in (M may be 0)."""
        self.has_anchor = True
        self.anchor_votes[cells[:, 0], cells[:, 1]] += 1

    def goal_rejected(self) -> None:
        """The committed goal was given up: its object evidence goes with it."""
        self.object_matches.clear()

    def wrong_room(self, room_belief: float | None = None) -> bool:
        """The room check fails (``room_belief``: the room map's belief in the instructed
        type at the robot's cell, None without one)."""
        threshold, keep = self.config.room_reject_threshold, self.config.room_map_keep
        if not (threshold > 0.0 and float(np.mean(self.room_matches)) < threshold):
            return False
        if keep > 0.0 and room_belief is not None and room_belief >= keep:
            self.room_map_kept += 1  # the map overruled the last ticks
            return False
        return True

    def wrong_object(self) -> bool:
        threshold = self.config.object_reject_threshold
        return (
            threshold > 0.0
            and len(self.object_matches) > 0
            and float(np.mean(self.object_matches)) < threshold
        )

    def anchor_cells(self, goal_votes: np.ndarray) -> np.ndarray:
        """(H, W) bool: the mapped anchor, given the ticks with goal pixels per cell
        ``goal_votes`` (H, W). With ``anchor_outvotes_goal`` a cell where goal pixels landed
        at least as often is the goal's (a few of its pixels read as the anchor), not the
        anchor's."""
        ticks = self.config.anchor_ticks or self.confirm_ticks
        anchor = self.anchor_votes >= ticks  # (H, W)
        if self.config.anchor_outvotes_goal:
            anchor &= self.anchor_votes > goal_votes
        return anchor

    def confirmed_goal(self, goal_votes: np.ndarray) -> np.ndarray:
        """(H, W) bool: the confirmed goal cells, given the ticks with goal pixels per cell
        ``goal_votes`` (H, W): ``confirm_ticks`` of them; with ``goal_yields_to_anchor`` a
        cell where anchor pixels landed on more ticks is the anchor's (the goal head read the
        anchor, e.g. the table of "the chair next to the table"), not the goal's."""
        confirmed = goal_votes >= self.confirm_ticks  # (H, W)
        if self.config.goal_yields_to_anchor and self.has_anchor:
            confirmed &= self.anchor_votes <= goal_votes
        return confirmed

    def anchor_distance(self, goal: np.ndarray, goal_votes: np.ndarray) -> float | None:
        """Metres (between cell centres) from the ``goal`` cells (H, W) bool to the nearest
        anchor cell (:meth:`anchor_cells` of ``goal_votes``): inf when none is mapped, None
        when the instruction names no anchor."""
        if not self.has_anchor:
            return None
        anchor = self.anchor_cells(goal_votes)  # (H, W)
        if not anchor.any() or not goal.any():
            return math.inf
        to_anchor = ndimage.distance_transform_edt(~anchor)  # (H, W) cells to the anchor
        return float(to_anchor[goal].min()) * self.cell_size

    def no_anchor_near(self, goal: np.ndarray, goal_votes: np.ndarray) -> bool:
        distance = self.config.relation_distance
        if distance <= 0.0:
            return False
        found = self.anchor_distance(goal, goal_votes)
        return found is not None and found > distance + 1e-9

    def failed(
        self,
        goal: Callable[[], np.ndarray],
        goal_votes: np.ndarray,
        room_belief: float | None = None,
    ) -> str | None:
        """The first check the goal near the robot fails ("room", "object", "relation"), or
        None; ``goal()`` gives its cells (H, W) (computed only when the relation check needs
        them), ``goal_votes`` (H, W) the ticks with goal pixels per cell, ``room_belief`` the
        room map's belief in the instructed room at the robot's cell (None: none)."""
        if self.wrong_room(room_belief):
            return "room"
        if self.wrong_object():
            return "object"
        return "relation" if self.no_anchor_near(goal(), goal_votes) else None

    def evidence(
        self, goal: np.ndarray | None, goal_votes: np.ndarray, room_belief: float | None = None
    ) -> dict:
        """The checks' inputs at a STOP (None where a check had none)."""
        distance = None if goal is None else self.anchor_distance(goal, goal_votes)
        return {
            "room_match": round(float(np.mean(self.room_matches)), 4),
            "room_belief": None if room_belief is None else round(room_belief, 4),
            "object_match": (
                round(float(np.mean(self.object_matches)), 4) if self.object_matches else None
            ),
            # None: no anchor named, or none mapped (then anchor_cells is 0)
            "anchor_distance": (
                None if distance is None or not math.isfinite(distance) else round(distance, 3)
            ),
            "anchor_cells": int(self.anchor_cells(goal_votes).sum()),
        }
