"""``DualSystemConfig``: every setting of the S2 planner + S1 controller (``model.dual_system``).

:class:`~vla_gr.core.dual_system.architecture.DualSystemArchitecture` is built from it; its
keyword constructor (the seed's call) fills one. Next in the data flow:
:mod:`vla_gr.core.dual_system.architecture`.
"""

from __future__ import annotations

from dataclasses import dataclass

from vla_gr.validation import check_choice, check_positive, check_positive_int

__all__ = ["GATES", "DualSystemConfig"]

GATES = ("confidence", "learned")


@dataclass
class DualSystemConfig:
    """The first six fields are the seed's positional arguments of ``DualSystemArchitecture``."""

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
            check_positive_int(f"model.dual_system.{key}", getattr(self, key))
        if self.goal_dim is not None:
            check_positive_int("model.dual_system.goal_dim", self.goal_dim)
        check_positive("model.dual_system.num_subgoals", self.num_subgoals, allow_zero=True)
        check_positive("model.dual_system.planning_frequency_hz", self.planning_frequency_hz)
        check_positive("model.dual_system.control_frequency_hz", self.control_frequency_hz)
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"model.dual_system.dropout={self.dropout!r} must be in [0, 1)")
        check_choice("model.dual_system.gate", self.gate, GATES)
