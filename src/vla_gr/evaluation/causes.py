"""Why an episode failed, decided from the episode's own record (pure functions).

One cause per failed episode, checked in this order:

- ``not_understood``: the agent declared that the request names nothing it can ground, and
  ended the episode without acting (``env.unwrapped.declare``);
- ``not_found``: the agent declared that it searched the reachable house and the goal is not
  in it;
- ``stopped_at_distractor``: STOP called within ``success_distance`` (geodesic) of another
  object of the goal's category;
- ``stopped_elsewhere``: any other wrong STOP;
- ``stuck`` (no STOP): every position of the last ``stuck_steps`` steps lies within
  ``stuck_radius`` of the final one (spinning in place, pinned against furniture);
- ``timeout_goal_never_seen``: the goal instance never covered ``goal_seen_pixels`` pixels
  of an observation;
- ``timeout_goal_seen``: the goal was seen but the budget ran out.

A wrong STOP is further told apart by the object nearest to where the robot stopped
(:func:`wrong_stop_kind`): another instance of the goal's category, an object of another
category in the goal's colour (the grounding followed the colour, not the category), or any
other object. A goal the planner *rejected* on the way (a failed goal check, a dead end, a
trap) is told apart the same way (:func:`rejected_goal_kind`): the goal instance itself (a
mistaken rejection), a same-category distractor, or anything else.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vla_gr.envs import DECLARED_OUTCOMES

CAUSES: tuple[str, ...] = (
    "stopped_at_distractor",
    "stopped_elsewhere",
    "stuck",
    "timeout_goal_never_seen",
    "timeout_goal_seen",
    *DECLARED_OUTCOMES,
)


WRONG_STOP_KINDS: tuple[str, ...] = ("same_category", "same_colour", "other_object")
REJECTED_GOAL_KINDS: tuple[str, ...] = ("goal", "same_category", "other_object")


@dataclass(frozen=True)
class CauseThresholds:
    """The knobs of :func:`failure_cause` (``eval.*`` config fields)."""

    success_distance: float = 1.0  # m
    goal_seen_pixels: int = 20
    stuck_steps: int = 50
    stuck_radius: float = 0.3  # m


def is_stuck(xy: np.ndarray, steps: int, radius: float) -> bool:
    """True when the last ``steps`` moves of ``xy`` (T+1, 2) stay within ``radius`` of the end."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) <= steps:
        return False
    window = xy[-(steps + 1) :]  # (steps + 1, 2)
    return bool(np.linalg.norm(window - window[-1], axis=1).max() < radius)


def failure_cause(
    success: bool,
    stopped: bool,
    xy: np.ndarray,
    goal_pixels: Sequence[int],
    distractor_distances: Sequence[float],
    th: CauseThresholds,
    declared: str | None = None,
) -> str | None:
    """The cause of a failed episode (None for a success); see the module docstring.

    ``xy`` (T+1, 2) world positions from the start, ``goal_pixels`` (T+1,) goal-instance
    pixel counts per observation, ``distractor_distances`` geodesic distances (m) from the
    final position to each same-category distractor, ``declared`` the outcome that ended the
    episode (``info["declared"]``; None when none was declared).
    """
    if declared is not None and declared not in DECLARED_OUTCOMES:
        raise ValueError(f"declared={declared!r}; valid: {', '.join(DECLARED_OUTCOMES)}")
    if success:
        return None
    if declared is not None:
        return declared
    if stopped:
        near = [d for d in distractor_distances if d <= th.success_distance]
        return "stopped_at_distractor" if near else "stopped_elsewhere"
    if is_stuck(xy, th.stuck_steps, th.stuck_radius):
        return "stuck"
    seen = len(goal_pixels) > 0 and max(goal_pixels) >= th.goal_seen_pixels
    return "timeout_goal_seen" if seen else "timeout_goal_never_seen"


def wrong_stop_kind(goal: dict, nearest: dict) -> str:
    """What a wrong STOP was next to: ``same_category`` (``nearest`` has the goal's category),
    ``same_colour`` (another category in the goal's colour) or ``other_object``.

    ``goal`` and ``nearest`` hold ``category`` and ``color`` (of the goal instance and of the
    object nearest to the final position).
    """
    if nearest["category"] == goal["category"]:
        return "same_category"
    if nearest["color"] == goal["color"]:
        return "same_colour"
    return "other_object"


def rejected_goal_kind(goal: dict, nearest: dict, near_distance: float) -> str:
    """What a goal the planner rejected was: ``goal`` (``nearest`` is the goal instance, at
    most ``near_distance`` m away: a right goal given up), ``same_category`` (a distractor) or
    ``other_object`` (another category, or nothing within ``near_distance``).

    ``goal`` and ``nearest`` hold ``instance_id`` and ``category``; ``nearest`` also holds
    ``distance`` (m) from the rejected goal cell to its footprint.
    """
    if nearest["distance"] > near_distance:
        return "other_object"
    if nearest["instance_id"] == goal["instance_id"]:
        return "goal"
    if nearest["category"] == goal["category"]:
        return "same_category"
    return "other_object"
