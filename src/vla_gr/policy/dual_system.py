"""The dual system at inference: S2 grounds the instruction and plans on the GR field, S1 drives.

One control step of :class:`GroundedDualSystem` (batch 1, the env's observation)::

    step     0    1    2    3    4    5    6  ...   (plan_every = 3; reset() -> step 0)
    S2       X    .    .    X    .    .    X        goal likelihood -> Navigator.plan()
    S1       X    X    X    X    X    X    X        S1 acts on the latest plan

S2 = a goal-likelihood source (the learned goal head of
:mod:`vla_gr.core.grounding`, or any callable; evaluation's privileged ablation passes the
true mask) + :class:`~vla_gr.core.gr_field.Navigator` (map, masses, potential, metric,
geodesic; look around, multi-tick confirmation, approach, verify, recover, stop), and, when
given, a room check (``room_match``: how likely the robot is in the room the instruction
names; the policy's room-type classifier, :mod:`vla_gr.core.grounding.room_type`) and an
object check (``object_evidence``: how likely the pixels the goal likelihood marks show the
instructed category, and where a relation's anchor is; see
:mod:`vla_gr.core.grounding.object_category`). S1
(``model.s1.kind``) = the learned :class:`~vla_gr.core.dual_system.LearnedFollower` (RGB-D +
the plan -> action chunk and STOP) or :class:`~vla_gr.core.dual_system.PurePursuit`; both
carry the plan's waypoints into the current robot frame by odometry between ticks. The
schedule is :func:`~vla_gr.core.dual_system.plan_interval` of the configured S2 and S1 rates.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

import numpy as np

from vla_gr.core.dual_system import (
    LearnedFollower,
    PurePursuit,
    PursuitConfig,
    S1Policy,
    plan_interval,
)
from vla_gr.core.gr_field import GRFieldConfig, Navigator, NavigatorConfig, NavPlan
from vla_gr.core.grounding import ObjectEvidence

__all__ = ["GoalLikelihood", "GroundedDualSystem", "ObjectCheck", "RoomMatch"]

#: ``(obs) -> (H, W)`` per-pixel probability that the pixel shows the instructed object, or
#: ``(obs) -> ((H, W), p)`` with ``p`` the probability that it is in view at all.
GoalLikelihood = Callable[[Mapping], np.ndarray | tuple[np.ndarray, float]]
#: ``(obs) -> p``: probability that the robot is in a room of the instructed type (1 when the
#: instruction names no room).
RoomMatch = Callable[[Mapping], float]
#: ``(obs, likelihood (H, W)) -> ObjectEvidence``: probability that the pixels the likelihood
#: marks show an object of the instructed category, and the anchor's per-pixel probability.
ObjectCheck = Callable[[Mapping, np.ndarray], ObjectEvidence]


class GroundedDualSystem:
    """S2 (goal likelihood + GR-field navigator) every ``plan_every`` steps, S1 every step.

    Args:
        goal_likelihood: the S2 perception, ``obs -> (H, W)`` in [0, 1] (or that and the
            probability that the goal is in view, see :data:`GoalLikelihood`).
        navigator, field, pursuit: configs of the navigator, its GR field and the follower.
        plan_every: control steps per S2 tick.
        s1: the learned S1 network; None = the pure-pursuit follower (``pursuit``).
        room_match: S2's room check (see :data:`RoomMatch`); None = every tick passes 1.
        object_evidence: S2's object checks (see :data:`ObjectCheck`); None = no evidence.
    """

    def __init__(
        self,
        goal_likelihood: GoalLikelihood,
        navigator: NavigatorConfig | None = None,
        field: GRFieldConfig | None = None,
        pursuit: PursuitConfig | None = None,
        plan_every: int = 1,
        s1: S1Policy | None = None,
        room_match: RoomMatch | None = None,
        object_evidence: ObjectCheck | None = None,
    ) -> None:
        self.goal_likelihood = goal_likelihood
        self.room_match = room_match
        self.object_evidence = object_evidence
        self.navigator = Navigator(navigator, field, plan_every=plan_every)
        if s1 is None:
            self.follower = PurePursuit(pursuit)
        else:
            guard = (pursuit or PursuitConfig()) if s1.config.depth_guard else None
            self.follower = LearnedFollower(s1, guard=guard)
        self.plan_every = self.navigator.plan_every
        #: seconds of the last step's parts: ``s1`` always; on planner ticks ``s2`` and its two
        #: parts, ``s2_perception`` (the goal likelihood) and ``s2_navigator`` (GR field + rules)
        self.last_timings: dict[str, float] = {}
        self.reset()

    @classmethod
    def from_model_config(
        cls,
        goal_likelihood: GoalLikelihood,
        model,
        s1: S1Policy | None = None,
        room_match: RoomMatch | None = None,
        object_evidence: ObjectCheck | None = None,
    ) -> GroundedDualSystem:
        """Built from a ``ModelConfig``: ``navigator``, ``gr_field``, the S1 of ``s1.kind``
        (``s1`` is the learned network, used when the kind is ``learned``) and the S2 schedule
        from ``dual_system``'s control and planning rates."""
        d = model.dual_system
        if model.s1.kind == "learned" and s1 is None:
            raise ValueError("model.s1.kind=learned needs the S1 network (s1=S1Policy(...))")
        return cls(
            goal_likelihood,
            navigator=model.navigator,
            field=model.gr_field,
            pursuit=model.pursuit,
            plan_every=plan_interval(d.control_frequency_hz, d.planning_frequency_hz),
            s1=s1 if model.s1.kind == "learned" else None,
            room_match=room_match,
            object_evidence=object_evidence,
        )

    def reset(self) -> None:
        """New episode: empty map, no plan; the next step runs S2."""
        self.navigator.reset()
        self.follower.reset()
        self.steps = 0
        self.plan: NavPlan | None = None
        self.last_likelihood: np.ndarray | None = None  # (H, W) of the last S2 tick
        self.max_goal_confidence = 0.0

    def episode_summary(self) -> dict:
        """What S2 concluded this episode: the highest goal confidence, the last mode, the
        goals it rejected (how many, and each one's reason, tick and position in the
        episode-start frame), the times it was trapped and the evidence behind its STOP
        request ({} without one)."""
        return {
            "goal_confidence": round(float(self.max_goal_confidence), 4),
            "last_mode": None if self.plan is None else self.plan.mode,
            "rejected_goals": int(self.navigator.rejections),
            "rejections": [dict(r) for r in self.navigator.rejection_log],
            "traps": int(self.navigator.traps),
            "stop_evidence": dict(self.navigator.stop_evidence),
        }

    def plan_if_due(self, obs: Mapping) -> dict[str, float] | None:
        """S2's part of a control step: on a planner tick, the goal likelihood (and the room
        and object checks) and a new plan (handed to the follower). Returns the tick's
        seconds (``s2``, ``s2_perception``, ``s2_navigator``), or None between ticks."""
        if self.steps % self.plan_every:
            return None
        t0 = time.perf_counter()
        depth = np.asarray(obs["depth"], dtype=np.float32)  # (H, W, 1)
        pose = np.asarray(obs["pose"], dtype=np.float64).reshape(3)  # (3,)
        perceived = self.goal_likelihood(obs)
        room_match = 1.0 if self.room_match is None else float(self.room_match(obs))
        likelihood, visible = perceived if isinstance(perceived, tuple) else (perceived, 1.0)
        likelihood = np.asarray(likelihood, dtype=np.float32)  # (H, W)
        if likelihood.shape != depth.shape[:2]:
            raise ValueError(
                f"goal likelihood has shape {likelihood.shape}, expected {depth.shape[:2]}"
            )
        evidence = (
            ObjectEvidence()
            if self.object_evidence is None
            else self.object_evidence(obs, likelihood)
        )
        t_perceived = time.perf_counter()
        self.plan = self.navigator.plan(
            {"depth": depth, "pose": pose}, likelihood, visible, room_match, *evidence
        )
        self.follower.set_plan(self.plan, pose)
        self.last_likelihood = likelihood
        self.max_goal_confidence = max(self.max_goal_confidence, self.plan.goal_confidence)
        t1 = time.perf_counter()
        return {"s2": t1 - t0, "s2_perception": t_perceived - t0, "s2_navigator": t1 - t_perceived}

    def step(self, obs: Mapping) -> np.ndarray:
        """One control step on a single env observation -> action float32 (3,) (v, w, stop)."""
        timings = self.plan_if_due(obs) or {}
        t1 = time.perf_counter()
        depth = np.asarray(obs["depth"], dtype=np.float32)  # (H, W, 1)
        pose = np.asarray(obs["pose"], dtype=np.float64).reshape(3)  # (3,)
        action = self.follower.act(depth, pose, rgb=obs["rgb"])  # (3,)
        timings["s1"] = time.perf_counter() - t1
        self.last_timings = timings
        self.steps += 1
        return action
