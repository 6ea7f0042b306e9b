"""``DualSystemArchitecture``: S2 (:mod:`.planner`) steering S1 (:mod:`.controller`) on a schedule.

As in GR00T N1 / Helix: S2 reads vision-language features at 1-5 Hz and emits a
latent goal, optional sub-goals and a confidence; S1 runs at the control rate on
the current visual features, proprioception and the *latest* latent goal.

Timeline of :meth:`DualSystemArchitecture.forward` in eval mode with
``control_frequency_hz=10`` and ``planning_frequency_hz=2`` (plan every 5 calls)::

    call     0    1    2    3    4    5    6  ...   (reset() -> call 0 again)
    S2       X    .    .    .    .    X    .        X: S2 runs, result cached
    S1       X    X    X    X    X    X    X        every call, latest goal

In training mode S2 runs on every call so that gradients reach the planner.
The threaded, non-blocking version of the same schedule is
:class:`vla_gr.core.dual_system.runner.DualSystemRunner`.

Next in the data flow: :mod:`vla_gr.core.dual_system.runner` (the threaded schedule).
"""

from __future__ import annotations

import logging

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.core.dual_system.config import DualSystemConfig
from vla_gr.core.dual_system.controller import S1Controller
from vla_gr.core.dual_system.planner import S2Planner

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------- pure maths


def plan_interval(control_frequency_hz: float, planning_frequency_hz: float) -> int:
    """Number of control calls per S2 call: ``max(1, round(control / planning))``."""
    if not control_frequency_hz > 0:
        raise ValueError(f"control_frequency_hz={control_frequency_hz!r} must be > 0")
    if not planning_frequency_hz > 0:
        raise ValueError(f"planning_frequency_hz={planning_frequency_hz!r} must be > 0")
    if planning_frequency_hz > control_frequency_hz:
        raise ValueError(
            f"planning_frequency_hz={planning_frequency_hz} must not exceed "
            f"control_frequency_hz={control_frequency_hz} (S2 is the slow system)"
        )
    return max(1, round(control_frequency_hz / planning_frequency_hz))


def confidence_targets(goal_error: torch.Tensor, reactive_error: torch.Tensor) -> torch.Tensor:
    """Calibration label: 1 where the goal-directed branch beats the reactive one.

    Args:
        goal_error: (B,) per-sample error of the goal-directed action.
        reactive_error: (B,) per-sample error of the reactive action.

    Returns:
        (B,) float tensor in {0, 1}, detached.
    """
    return (goal_error < reactive_error).to(goal_error.dtype).detach()  # (B,)


class DualSystemArchitecture(nn.Module):
    """S2 planner + S1 controller with S2 cached between planning ticks.

    Built from a :class:`~vla_gr.core.dual_system.config.DualSystemConfig` (every setting and
    its default live there), or with the seed's call, which fills one:
    ``DualSystemArchitecture(visual_dim, vlm_dim, s1_hidden_dim, s2_hidden_dim,
    planning_frequency_hz, control_frequency_hz, ...)``. S2 runs every
    ``round(control / planning)`` calls.
    """

    def __init__(self, *args, config: DualSystemConfig | None = None, **kwargs) -> None:
        super().__init__()
        if config is None:
            config = DualSystemConfig(*args, **kwargs)
        elif args or kwargs:
            raise ValueError("pass either a DualSystemConfig or keyword arguments, not both")
        self.config = c = config
        self.plan_every = plan_interval(c.control_frequency_hz, c.planning_frequency_hz)
        self.visual_dim, self.vlm_dim = c.visual_dim, c.vlm_dim
        self.action_dim, self.proprio_dim = c.action_dim, c.proprio_dim
        self.goal_dim = c.goal_dim or c.s1_hidden_dim
        self.planning_frequency_hz = float(c.planning_frequency_hz)
        self.control_frequency_hz = float(c.control_frequency_hz)
        self.s2 = S2Planner(
            c.vlm_dim,
            c.s2_hidden_dim,
            self.goal_dim,
            c.num_subgoals,
            c.s2_num_layers,
            c.s2_num_heads,
            c.dropout,
        )
        self.s1 = S1Controller(
            c.visual_dim,
            c.proprio_dim,
            self.goal_dim,
            c.s1_hidden_dim,
            c.action_dim,
            c.s1_num_layers,
            c.gate,
            c.dropout,
        )
        self.s2_calls = 0  # total S2 evaluations since construction (diagnostics)
        self.reset()

    # ------------------------------------------------------------------ state

    def reset(self) -> None:
        """Drop the cached plan; the next call runs S2."""
        self._plan: dict[str, torch.Tensor | None] | None = None
        self._steps_since_plan = 0

    def _needs_plan(self, batch_size: int, device: torch.device, force_plan: bool) -> bool:
        if force_plan or self.training or self._plan is None:
            return True
        goal = self._plan["latent_goal"]
        if goal.shape[0] != batch_size or goal.device != device:
            return True
        return self._steps_since_plan >= self.plan_every

    # ------------------------------------------------------------------ stateless parts

    def plan(
        self, vlm_features: torch.Tensor, vlm_mask: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor | None]:
        """Run S2 once (no caching); see :meth:`S2Planner.forward` for shapes."""
        self._check_features("vlm_features", vlm_features, self.vlm_dim)
        self.s2_calls += 1
        return self.s2(vlm_features, vlm_mask)

    def act(
        self,
        visual_features: torch.Tensor,
        proprioception: torch.Tensor | None,
        latent_goal: torch.Tensor,
        confidence: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """Run S1 once on a given plan; see :meth:`S1Controller.forward` for shapes."""
        self._check_features("visual_features", visual_features, self.visual_dim)
        B = visual_features.shape[0]
        if proprioception is None:
            proprioception = visual_features.new_zeros(B, self.proprio_dim)  # (B, P)
        self._check_features("proprioception", proprioception, self.proprio_dim, (2,))
        if proprioception.shape[0] != B:
            raise ValueError(
                f"proprioception batch {proprioception.shape[0]} != visual_features batch {B}"
            )
        if latent_goal.shape != (B, self.goal_dim):
            raise ValueError(
                f"latent_goal has shape {tuple(latent_goal.shape)}, expected ({B}, {self.goal_dim})"
            )
        return self.s1(visual_features, proprioception, latent_goal, confidence)

    @staticmethod
    def _check_features(name: str, x: torch.Tensor, dim: int, ndims=(2, 3)) -> None:
        if not isinstance(x, torch.Tensor):
            raise ValueError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
        if x.dim() not in ndims or x.shape[-1] != dim:
            want = " or ".join(f"{n}-D" for n in ndims)
            raise ValueError(
                f"{name} has shape {tuple(x.shape)}; expected {want} with last dim {dim}"
            )

    # ------------------------------------------------------------------ forward / loss

    def forward(
        self,
        visual_features: torch.Tensor,
        vlm_features: torch.Tensor,
        proprioception: torch.Tensor | None = None,
        vlm_mask: torch.Tensor | None = None,
        force_plan: bool = False,
    ) -> dict[str, torch.Tensor | bool | None]:
        """One control tick.

        Args:
            visual_features: (B, visual_dim) or (B, T, visual_dim) current observation.
            vlm_features: (B, vlm_dim) or (B, T, vlm_dim); only read when S2 runs.
            proprioception: (B, proprio_dim); zeros when None.
            vlm_mask: optional (B, T) bool validity mask of the VLM tokens.
            force_plan: run S2 now and restart the planning schedule.

        Returns:
            ``action`` (B, A), ``goal_action`` (B, A), ``reactive_action`` (B, A),
            ``gate`` (B,), ``latent_goal`` (B, G), ``subgoals`` (B, K, G) or None,
            ``confidence`` (B,), ``confidence_logit`` (B,), ``s2_ran`` bool.
        """
        self._check_features("visual_features", visual_features, self.visual_dim)
        B = visual_features.shape[0]
        s2_ran = self._needs_plan(B, visual_features.device, force_plan)
        if s2_ran:
            if vlm_features.shape[0] != B:
                raise ValueError(f"vlm_features batch {vlm_features.shape[0]} != {B}")
            plan = self.plan(vlm_features, vlm_mask)
            # Cache a detached copy; in training mode the live tensors are used below.
            self._plan = {k: (v.detach() if v is not None else None) for k, v in plan.items()}
            self._steps_since_plan = 0
        else:
            plan = self._plan
        self._steps_since_plan += 1
        out = self.act(visual_features, proprioception, plan["latent_goal"], plan["confidence"])
        return {**plan, **out, "s2_ran": s2_ran}

    def compute_loss(
        self,
        visual_features: torch.Tensor,
        vlm_features: torch.Tensor,
        proprioception: torch.Tensor | None,
        target_actions: torch.Tensor,
        vlm_mask: torch.Tensor | None = None,
        subgoal_targets: torch.Tensor | None = None,
        branch_weight: float = 0.5,
        confidence_weight: float = 0.1,
    ) -> dict[str, torch.Tensor]:
        """Training loss with S2 run on this call (gradients reach both systems).

        ``loss = mse(action) + branch_weight * (mse(goal) + mse(reactive))
        + confidence_weight * BCE(confidence, [goal error < reactive error])
        (+ mse(subgoals) when targets are given)``. The calibration term teaches
        S2 to be confident exactly when following its goal beats reacting.

        Args:
            target_actions: (B, A) expert actions.
            subgoal_targets: optional (B, K, G) sub-goal targets.
            Other arguments as in :meth:`forward`.

        Returns:
            ``loss`` (scalar) and detached scalars ``action_loss``, ``branch_loss``,
            ``confidence_loss``, ``confidence_mean``, ``confidence_target_mean``.
        """
        if target_actions.shape[-1] != self.action_dim or target_actions.dim() != 2:
            raise ValueError(
                f"target_actions has shape {tuple(target_actions.shape)}; "
                f"expected (B, {self.action_dim})"
            )
        out = self.forward(
            visual_features, vlm_features, proprioception, vlm_mask=vlm_mask, force_plan=True
        )
        action_loss = F.mse_loss(out["action"], target_actions)
        goal_err = (out["goal_action"] - target_actions).pow(2).mean(-1)  # (B,)
        reactive_err = (out["reactive_action"] - target_actions).pow(2).mean(-1)  # (B,)
        branch_loss = goal_err.mean() + reactive_err.mean()
        target_c = confidence_targets(goal_err, reactive_err)  # (B,)
        confidence_loss = F.binary_cross_entropy_with_logits(out["confidence_logit"], target_c)
        loss = action_loss + branch_weight * branch_loss + confidence_weight * confidence_loss
        result = {}
        if subgoal_targets is not None:
            if out["subgoals"] is None or subgoal_targets.shape != out["subgoals"].shape:
                raise ValueError(
                    f"subgoal_targets has shape {tuple(subgoal_targets.shape)}; expected "
                    f"{None if out['subgoals'] is None else tuple(out['subgoals'].shape)}"
                )
            subgoal_loss = F.mse_loss(out["subgoals"], subgoal_targets)
            loss = loss + subgoal_loss
            result["subgoal_loss"] = subgoal_loss.detach()
        result.update(
            loss=loss,
            action_loss=action_loss.detach(),
            branch_loss=branch_loss.detach(),
            confidence_loss=confidence_loss.detach(),
            confidence_mean=out["confidence"].mean().detach(),
            confidence_target_mean=target_c.mean(),
        )
        return result

    def num_parameters(self) -> dict[str, int]:
        """Parameter counts of ``s1``, ``s2`` and ``total``."""
        s1 = sum(p.numel() for p in self.s1.parameters())
        s2 = sum(p.numel() for p in self.s2.parameters())
        return {"s1": s1, "s2": s2, "total": s1 + s2}
