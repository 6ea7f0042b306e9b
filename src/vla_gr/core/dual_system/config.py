"""The dual system's configs: the seed's building block, the agent's schedule and its S1.

- ``DualSystemConfig``: every setting of the seed's latent S2 planner + S1 controller;
  :class:`~vla_gr.core.dual_system.architecture.DualSystemArchitecture` is built from it and its
  keyword constructor (the seed's call) fills one. No agent runs that block, so it is no
  section of ``model``;
- ``ScheduleConfig`` (``model.schedule``): the VLA-GR agent's S2 and S1 rates;
- ``S1Config`` (``model.s1``): the agent's S1.

Next in the data flow: :mod:`vla_gr.core.dual_system.architecture`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vla_gr.core.diffusion_policy.config import HeadConfig
from vla_gr.validation import check_choice, check_positive, check_positive_int

__all__ = ["GATES", "S1_KINDS", "DualSystemConfig", "S1Config", "ScheduleConfig"]

GATES = ("confidence", "learned")
#: S1 of the grounded dual system: the learned controller, or the pure-pursuit follower.
S1_KINDS = ("learned", "pure_pursuit")
_BLOCK = "DualSystemConfig"  # the seed's block: no model key


def _s1_head() -> HeadConfig:
    """S1's action head: a small flow-matching U-Net over (v, w) chunks of 8 steps."""
    return HeadConfig(
        action_dim=2,
        hidden_dim=64,
        objective="flow_matching",
        horizon=8,
        num_inference_steps=4,
    )


@dataclass
class DualSystemConfig:
    """The seed's ``DualSystemArchitecture`` (its first six fields are the seed's positional
    arguments); errors name ``DualSystemConfig.<field>``."""

    visual_dim: int = 512  # width of the visual features given to S1
    vlm_dim: int = 768  # width of the vision-language features given to S2
    s1_hidden_dim: int = 256  # S1 trunk width (S1 stays <= 2 M parameters)
    s2_hidden_dim: int = 512  # S2 transformer width
    planning_frequency_hz: float = 2.0  # S2 rate
    control_frequency_hz: float = 20.0  # S1 rate (one forward call per control tick)
    action_dim: int = 7
    proprio_dim: int = 7
    goal_dim: int | None = None  # latent goal width; None = s1_hidden_dim
    num_subgoals: int = 4  # sub-goal tokens emitted by S2 (0 disables them)
    s1_num_layers: int = 2
    s2_num_layers: int = 2
    s2_num_heads: int = 8
    dropout: float = 0.0
    gate: str = "confidence"  # c * goal + (1 - c) * reactive, or a learned correction

    def __post_init__(self) -> None:
        for key in (
            "visual_dim", "vlm_dim", "s1_hidden_dim", "s2_hidden_dim", "action_dim",
            "proprio_dim", "s1_num_layers", "s2_num_layers", "s2_num_heads",
        ):  # fmt: skip
            check_positive_int(f"{_BLOCK}.{key}", getattr(self, key))
        if self.goal_dim is not None:
            check_positive_int(f"{_BLOCK}.goal_dim", self.goal_dim)
        check_positive(f"{_BLOCK}.num_subgoals", self.num_subgoals, allow_zero=True)
        check_positive(f"{_BLOCK}.planning_frequency_hz", self.planning_frequency_hz)
        check_positive(f"{_BLOCK}.control_frequency_hz", self.control_frequency_hz)
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"{_BLOCK}.dropout={self.dropout!r} must be in [0, 1)")
        check_choice(f"{_BLOCK}.gate", self.gate, GATES)


@dataclass
class ScheduleConfig:
    """When the VLA-GR agent's S2 and S1 run (``model.schedule``): S2 plans every
    :func:`~vla_gr.core.dual_system.architecture.plan_interval` (control / planning rate,
    rounded) control steps, S1 acts on every one."""

    planning_frequency_hz: float = 2.0  # S2 rate
    control_frequency_hz: float = 20.0  # S1 rate (one action per control step)

    def __post_init__(self) -> None:
        check_positive("model.schedule.planning_frequency_hz", self.planning_frequency_hz)
        check_positive("model.schedule.control_frequency_hz", self.control_frequency_hz)


@dataclass
class S1Config:
    """S1 of the grounded dual system (``model.s1``): what drives between S2 ticks.

    ``kind=learned`` runs :class:`~vla_gr.agent.followers.learned_s1.S1Policy` (its own RGB-D
    encoder at ``image_size``, the latest plan as a vector, an action chunk from ``head`` and
    a STOP probability); ``pure_pursuit`` runs the non-learned follower (``model.pursuit``)
    on the same plans. ``use_s2=false`` never hands S1 a plan (the "without S2" ablation).
    """

    kind: str = "pure_pursuit"  # until S1 is trained (a recipe's s1 stage)
    image_size: int = 32  # S1's RGB-D input is average-pooled to this square size
    channels: list[int] = field(default_factory=lambda: [16, 32, 48, 64])  # conv stages
    dim: int = 96  # token width; the head's context_dim follows it (S1Policy sets it)
    max_depth: float = 10.0  # depth is divided by this (the env's max depth)
    path_points: list[float] = field(default_factory=lambda: [0.25, 0.5, 1.0, 2.0])  # m
    n_action_steps: int = 2  # chunk actions executed before S1 decides again
    stop_threshold: float = 0.5  # STOP when its probability is above this
    stop_weight: float = 1.0  # weight of the STOP BCE in the training loss
    use_s2: bool = True
    # the pure-pursuit follower's depth check on the learned S1's forward speed (model.pursuit's
    # corridor, stop_distance and slow_distance): a safety layer, not a learned behaviour
    depth_guard: bool = False
    head: HeadConfig = field(default_factory=_s1_head)

    def __post_init__(self) -> None:
        check_choice("model.s1.kind", self.kind, S1_KINDS)
        if not 8 <= self.image_size <= 128:
            raise ValueError(f"model.s1.image_size={self.image_size} must be in [8, 128]")
        if not self.channels or any(int(c) < 1 for c in self.channels):
            raise ValueError(f"model.s1.channels={list(self.channels)} must be positive widths")
        if self.image_size % 2 ** len(self.channels):
            raise ValueError(
                f"model.s1.image_size={self.image_size} must be divisible by "
                f"{2 ** len(self.channels)} (one stride-2 stage per model.s1.channels entry)"
            )
        check_positive_int("model.s1.dim", self.dim)
        if self.head.context_dim not in (None, self.dim):
            raise ValueError(
                f"model.s1.head.context_dim={self.head.context_dim} contradicts "
                f"model.s1.dim={self.dim}; set model.s1.dim instead"
            )
        check_positive("model.s1.max_depth", self.max_depth)
        if not self.path_points or any(not p > 0 for p in self.path_points):
            raise ValueError(f"model.s1.path_points={list(self.path_points)} must be > 0 m")
        check_positive_int("model.s1.n_action_steps", self.n_action_steps)
        if self.n_action_steps > self.head.horizon:
            raise ValueError(
                f"model.s1.n_action_steps={self.n_action_steps} must be <= "
                f"model.s1.head.horizon={self.head.horizon}"
            )
        if not 0.0 < self.stop_threshold < 1.0:
            raise ValueError(f"model.s1.stop_threshold={self.stop_threshold} must be in (0, 1)")
        check_positive("model.s1.stop_weight", self.stop_weight, allow_zero=True)
        if self.head.action_dim != 2:
            raise ValueError(
                f"model.s1.head.action_dim={self.head.action_dim} must be 2: S1's chunk is "
                "(v, w); STOP has its own output"
            )
