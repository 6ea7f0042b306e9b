"""The dual system at inference: S2 perceives and plans on the GR field, S1 drives.

One control step of :class:`GroundedDualSystem` (batch 1, the env's observation)::

    step     0    1    2    3    4    5    6  ...   (plan_every = 3; reset() -> step 0)
    S2       X    .    .    X    .    .    X        perception.perceive() -> Navigator.plan()
    S1       X    X    X    X    X    X    X        S1 acts on the latest plan

Before its first step the request is read (the perception's reader); a request it did not
understand is not acted on: the step returns no motion and no STOP, and
:attr:`GroundedDualSystem.declared_outcome` says ``"not_understood"`` (the caller ends the
episode with ``env.unwrapped.declare``). A plan that says the reachable house is searched
without a goal (``NavPlan.not_found``, the navigator's own map) ends it the same way, as
``"not_found"``.

S2 = a perception (:mod:`vla_gr.agent.perception.percept`: one typed percept per tick: the goal
likelihood, the room and object checks, the relation's anchor) + the
:class:`~vla_gr.core.gr_field.Navigator` (map, masses, potential, metric, geodesic; look
around, multi-tick confirmation, approach, verify, recover, stop). S1 (``model.s1.kind``) =
the learned :class:`~vla_gr.core.dual_system.LearnedFollower` (RGB-D + the plan -> action
chunk and STOP) or :class:`~vla_gr.core.dual_system.PurePursuit`; both carry the plan's
waypoints into the current robot frame by odometry between ticks. The schedule is
:func:`~vla_gr.core.dual_system.plan_interval` of the configured S2 and S1 rates
(``model.schedule``).
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from vla_gr.agent.followers import LearnedFollower, PurePursuit, PursuitConfig, S1Policy
from vla_gr.agent.navigator import Navigator, NavigatorConfig, NavPlan
from vla_gr.agent.perception.percept import Percept, Perception
from vla_gr.agent.reading import Reading
from vla_gr.core.dual_system import plan_interval
from vla_gr.core.gr_field import GRFieldConfig

__all__ = ["GroundedDualSystem"]


class GroundedDualSystem:
    """S2 (perception + GR-field navigator) every ``plan_every`` steps, S1 every step.

    Args:
        perception: S2's perception (:class:`~vla_gr.agent.perception.percept.Perception`).
        navigator, field, pursuit: configs of the navigator, its GR field and the follower;
            the navigator's drive test is handed the follower's ``pursuit.lookahead``.
        plan_every: control steps per S2 tick.
        s1: the learned S1 network; None = the pure-pursuit follower (``pursuit``).
    """

    def __init__(
        self,
        perception: Perception,
        navigator: NavigatorConfig | None = None,
        field: GRFieldConfig | None = None,
        pursuit: PursuitConfig | None = None,
        plan_every: int = 1,
        s1: S1Policy | None = None,
    ) -> None:
        self.perception = perception
        pursuit_config = pursuit or PursuitConfig()
        self.navigator = Navigator(
            navigator, field, plan_every=plan_every, lookahead=pursuit_config.lookahead
        )
        if s1 is None:
            self.follower = PurePursuit(pursuit)
        else:
            guard = pursuit_config if s1.config.depth_guard else None
            self.follower = LearnedFollower(s1, guard=guard)
        self.plan_every = self.navigator.plan_every
        #: seconds of the last step's parts: ``s1`` always; on planner ticks ``s2`` and its two
        #: parts, ``s2_perception`` (the percept) and ``s2_navigator`` (GR field + rules); on
        #: an episode's first step ``read`` (the request read into fields, once per episode)
        self.last_timings: dict[str, float] = {}
        self.reset()

    @classmethod
    def from_model_config(
        cls, perception: Perception, model, s1: S1Policy | None = None
    ) -> GroundedDualSystem:
        """Built from a ``ModelConfig``: ``navigator``, ``gr_field``, the S1 of ``s1.kind``
        (``s1`` is the learned network, used when the kind is ``learned``) and the S2 schedule
        from ``schedule``'s control and planning rates."""
        rates = model.schedule
        if model.s1.kind == "learned" and s1 is None:
            raise ValueError("model.s1.kind=learned needs the S1 network (s1=S1Policy(...))")
        return cls(
            perception,
            navigator=model.navigator,
            field=model.gr_field,
            pursuit=model.pursuit,
            plan_every=plan_interval(rates.control_frequency_hz, rates.planning_frequency_hz),
            s1=s1 if model.s1.kind == "learned" else None,
        )

    def reset(self) -> None:
        """New episode: empty map, no plan; the next step runs S2."""
        self.perception.reset()
        self.navigator.reset()
        self.follower.reset()
        self.steps = 0
        self.plan: NavPlan | None = None
        self.last_percept: Percept | None = None  # of the last S2 tick
        self.max_goal_confidence = 0.0
        self.reading: Reading | None = None  # this episode's request, once read
        # "not_understood" or "not_found": it does not act (any more)
        self.declared_outcome: str | None = None

    def episode_summary(self) -> dict:
        """What S2 concluded this episode: the highest goal confidence, the last mode, the
        goals it rejected (how many, and each one's reason, tick and position in the
        episode-start frame), the times it was trapped, the ticks the room map kept a goal
        the room check's last ticks would have rejected, the evidence behind its STOP request
        ({} without one)."""
        summary = {
            "goal_confidence": round(float(self.max_goal_confidence), 4),
            "last_mode": None if self.plan is None else self.plan.mode,
            "rejected_goals": int(self.navigator.rejections),
            "rejections": [dict(r) for r in self.navigator.rejection_log],
            "traps": int(self.navigator.traps),
            "room_map_kept": int(self.navigator.checks.room_map_kept),
            "stop_evidence": dict(self.navigator.stop_evidence),
        }
        return summary

    def plan_if_due(self, obs: Mapping) -> dict[str, float] | None:
        """S2's part of a control step: on a planner tick, one percept and a new plan
        (handed to the follower). Returns the tick's seconds (``s2``, ``s2_perception``,
        ``s2_navigator``), or None between ticks."""
        if self.steps % self.plan_every:
            return None
        t0 = time.perf_counter()
        depth = np.asarray(obs["depth"], dtype=np.float32)  # (H, W, 1)
        pose = np.asarray(obs["pose"], dtype=np.float64).reshape(3)  # (3,)
        p = self.perception.perceive(obs)
        t_perceived = time.perf_counter()
        self.plan = self.navigator.plan(
            {"depth": depth, "pose": pose},
            p.likelihood,
            p.visible,
            p.room_match,
            p.category_match,
            p.anchor,
            p.room_probs,
        )
        self.follower.set_plan(self.plan, pose)
        self.last_percept = p
        self.max_goal_confidence = max(self.max_goal_confidence, self.plan.goal_confidence)
        t1 = time.perf_counter()
        return {"s2": t1 - t0, "s2_perception": t_perceived - t0, "s2_navigator": t1 - t_perceived}

    def step(self, obs: Mapping) -> np.ndarray:
        """One control step on a single env observation -> action float32 (3,) (v, w, stop);
        no motion and no STOP, with ``declared_outcome`` set, for a request not understood or
        once the plan says the object is not found."""
        read = {}
        if self.steps == 0 or self.reading is not None:  # read once; later steps hit its cache
            t0 = time.perf_counter()
            self.reading = self.perception.read(obs["instruction"])
            if self.steps == 0:
                read["read"] = time.perf_counter() - t0  # the episode's one reading
            if self.reading is not None and not self.reading.understood:
                return self._declare("not_understood", read)
            if self.steps == 0 and self.reading is not None:  # where to search for it first
                self.navigator.set_search_goal(self.reading.category, self.reading.room)
        if self.declared_outcome == "not_found":  # declared: asked again, it stays declared
            return self._declare("not_found", read)
        timings = (self.plan_if_due(obs) or {}) | read
        if self.plan is not None and self.plan.not_found:
            return self._declare("not_found", timings)
        t1 = time.perf_counter()
        depth = np.asarray(obs["depth"], dtype=np.float32)  # (H, W, 1)
        pose = np.asarray(obs["pose"], dtype=np.float64).reshape(3)  # (3,)
        action = self.follower.act(depth, pose, rgb=obs["rgb"])  # (3,)
        timings["s1"] = time.perf_counter() - t1
        self.last_timings = timings
        self.steps += 1
        return action

    def _declare(self, outcome: str, timings: dict[str, float]) -> np.ndarray:
        """Declare ``outcome`` instead of acting: no motion, no STOP (float32 (3,) zeros)."""
        self.declared_outcome = outcome
        self.last_timings = timings
        self.steps += 1
        return np.zeros(3, dtype=np.float32)
