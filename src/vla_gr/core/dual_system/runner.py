"""Real-time dual-system runner: S2 in a background thread, S1 never waits for it.

The planner thread runs :meth:`DualSystemArchitecture.plan` at
``planning_frequency_hz`` on the newest planner input and publishes each result
into a :class:`LatestSlot`. :meth:`DualSystemRunner.step` (the control loop's
call, S1) reads the newest published plan without waiting and acts on it.

Double buffering: the planner builds every plan in fresh tensors (the *back*
buffer) that nobody else can see, then swaps one reference under a lock held for
a pointer assignment only; a reader keeps its snapshot (the *front* buffer) for
as long as it likes because published tensors are never mutated. Until the first
plan arrives S1 acts purely reactively (zero goal, confidence 0).

Usage::

    with DualSystemRunner(model) as runner:
        runner.set_planner_input(vlm_features)          # (1, T, vlm_dim)
        while running:
            out = runner.step(visual_features, proprio)  # never blocks on S2

Last step of the dual system: S1's action at the control rate.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import torch

from vla_gr.core.dual_system.architecture import DualSystemArchitecture

logger = logging.getLogger(__name__)


class LatestSlot:
    """Lock-protected latest-value slot with a version counter (writer never waits long)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._value: Any = None
        self._version = 0

    def put(self, value: Any) -> int:
        """Publish ``value`` (must not be mutated afterwards); returns its version."""
        with self._lock:
            self._value = value
            self._version += 1
            return self._version

    def get(self) -> tuple[Any, int]:
        """Newest ``(value, version)``; ``(None, 0)`` before the first put."""
        with self._lock:
            return self._value, self._version


@dataclass(frozen=True)
class Plan:
    """One published S2 result (immutable snapshot).

    ``latent_goal`` (B, G), ``confidence`` (B,), ``subgoals`` (B, K, G) or None;
    ``created`` is the ``time.perf_counter()`` at publication, ``latency_s`` the
    S2 compute time, ``index`` the plan's sequence number (1-based).
    """

    latent_goal: torch.Tensor
    confidence: torch.Tensor
    subgoals: torch.Tensor | None
    created: float
    latency_s: float
    index: int


class DualSystemRunner:
    """Run S2 asynchronously at its own rate and S1 synchronously on demand.

    Args:
        model: the dual system (put in eval mode by the runner).
        planning_frequency_hz: S2 rate; defaults to ``model.planning_frequency_hz``.
        join_timeout_s: how long :meth:`stop` waits for the planner thread.
    """

    def __init__(
        self,
        model: DualSystemArchitecture,
        planning_frequency_hz: float | None = None,
        join_timeout_s: float = 5.0,
    ) -> None:
        if not isinstance(model, DualSystemArchitecture):
            raise ValueError(f"model must be a DualSystemArchitecture, got {type(model).__name__}")
        hz = model.planning_frequency_hz if planning_frequency_hz is None else planning_frequency_hz
        if not hz > 0:
            raise ValueError(f"planning_frequency_hz={hz!r} must be > 0")
        self.model = model.eval()
        self.period_s = 1.0 / float(hz)
        self.join_timeout_s = join_timeout_s
        self._inputs = LatestSlot()  # newest (vlm_features, vlm_mask)
        self._plans = LatestSlot()  # newest Plan
        self._input_ready = threading.Event()
        self._epoch_lock = threading.Lock()  # orders reset() against plan publication
        self._epoch = 0  # bumped by reset(); plans of an older epoch are dropped
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._error_reported = False
        self.plan_times: list[float] = []  # perf_counter() of each publication
        self.overruns = 0  # plans that took longer than one period

    # ------------------------------------------------------------------ lifecycle

    @property
    def running(self) -> bool:
        """Whether the planner thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> DualSystemRunner:
        """Start the planner thread (idempotent while running)."""
        if self.running:
            return self
        self._stop.clear()
        self._error, self._error_reported = None, False
        self._thread = threading.Thread(target=self._planner_loop, name="s2-planner", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop and join the planner thread; re-raise an S2 error not yet surfaced."""
        self._stop.set()
        self._input_ready.set()  # wake a thread waiting for its first input
        if self._thread is not None:
            self._thread.join(self.join_timeout_s)
            if self._thread.is_alive():
                logger.warning("S2 planner thread did not stop within %.1f s", self.join_timeout_s)
            self._thread = None
        self._raise_if_failed()

    def __enter__(self) -> DualSystemRunner:
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self._error_reported = True  # do not mask the caller's exception
        self.stop()

    def reset(self) -> None:
        """Forget the published plan and planner input (new episode).

        A plan being computed while this runs is discarded, never published.
        """
        with self._epoch_lock:
            self._epoch += 1
            self._plans.put(None)
            self._inputs.put(None)
            self._input_ready.clear()

    # ------------------------------------------------------------------ planner side

    def set_planner_input(
        self, vlm_features: torch.Tensor, vlm_mask: torch.Tensor | None = None
    ) -> None:
        """Hand S2 its newest input (non-blocking).

        Args:
            vlm_features: (B, T, vlm_dim) or (B, vlm_dim).
            vlm_mask: optional (B, T) bool validity mask.
        """
        self.model._check_features("vlm_features", vlm_features, self.model.vlm_dim)
        with self._epoch_lock:
            self._inputs.put((self._epoch, vlm_features.detach(), vlm_mask))
            self._input_ready.set()

    def _planner_loop(self) -> None:
        next_tick = time.perf_counter()
        try:
            while not self._stop.is_set():
                if not self._input_ready.wait(timeout=0.05):
                    next_tick = time.perf_counter()
                    continue
                item, _ = self._inputs.get()
                if item is None:  # after reset(): sleep until the next input
                    with self._epoch_lock:
                        if self._inputs.get()[0] is None:
                            self._input_ready.clear()
                    continue
                epoch, vlm_features, vlm_mask = item
                t0 = time.perf_counter()
                with torch.inference_mode():  # grad mode is thread-local
                    out = self.model.plan(vlm_features, vlm_mask)
                t1 = time.perf_counter()
                if self._stop.is_set():
                    break
                plan = Plan(
                    latent_goal=out["latent_goal"],
                    confidence=out["confidence"],
                    subgoals=out["subgoals"],
                    created=t1,
                    latency_s=t1 - t0,
                    index=len(self.plan_times) + 1,
                )
                with self._epoch_lock:
                    if epoch != self._epoch:  # reset() ran meanwhile: stale plan
                        continue
                    self._plans.put(plan)
                    self.plan_times.append(t1)
                next_tick += self.period_s
                delay = next_tick - time.perf_counter()
                if delay < 0:  # overran the period: re-anchor instead of bursting
                    self.overruns += 1
                    next_tick = time.perf_counter()
                else:
                    self._stop.wait(delay)
        except BaseException as exc:  # surfaced to the control thread
            logger.exception("S2 planner thread failed")
            self._error = exc

    def _raise_if_failed(self) -> None:
        if self._error is not None and not self._error_reported:
            self._error_reported = True
            raise RuntimeError(f"S2 planner thread failed: {self._error!r}") from self._error

    # ------------------------------------------------------------------ control side

    def latest_plan(self) -> Plan | None:
        """Newest published plan (None before the first), without waiting."""
        return self._plans.get()[0]

    def wait_for_plan(self, timeout_s: float = 5.0) -> Plan:
        """Block until a plan exists (set-up only, never in the control loop)."""
        deadline = time.perf_counter() + timeout_s
        while (plan := self.latest_plan()) is None:
            self._raise_if_failed()
            if time.perf_counter() > deadline:
                raise TimeoutError(f"no S2 plan within {timeout_s} s")
            time.sleep(0.002)
        return plan

    @torch.inference_mode()
    def step(
        self,
        visual_features: torch.Tensor,
        proprioception: torch.Tensor | None = None,
        vlm_features: torch.Tensor | None = None,
    ) -> dict[str, Any]:
        """One S1 control step on the newest plan; never waits for S2.

        Args:
            visual_features: (B, visual_dim) or (B, T, visual_dim).
            proprioception: (B, proprio_dim) or None.
            vlm_features: optional new S2 input, handed over without waiting.

        Returns:
            S1 outputs (``action`` (B, A), ``gate`` (B,), ...) plus ``plan_index``
            (0 = no plan yet) and ``plan_age_s`` (seconds since publication).
        """
        self._raise_if_failed()
        if vlm_features is not None:
            self.set_planner_input(vlm_features)
        plan = self.latest_plan()
        B = visual_features.shape[0]
        if plan is None or plan.latent_goal.shape[0] != B:
            goal = visual_features.new_zeros(B, self.model.goal_dim)  # (B, G)
            confidence = visual_features.new_zeros(B)  # (B,) -> purely reactive
            index, age = 0, float("inf")
        else:
            goal, confidence = plan.latent_goal, plan.confidence
            index, age = plan.index, time.perf_counter() - plan.created
        out = self.model.act(visual_features, proprioception, goal, confidence)
        return {**out, "latent_goal": goal, "plan_index": index, "plan_age_s": age}

    def measured_rate_hz(self) -> float:
        """Plans per second over the published plans (0 with fewer than two)."""
        if len(self.plan_times) < 2:
            return 0.0
        span = self.plan_times[-1] - self.plan_times[0]
        return (len(self.plan_times) - 1) / span if span > 0 else 0.0
