"""Dual system: a slow planner S2 steering a fast reactive controller S1.

Data flow: :mod:`.config` (``DualSystemConfig``) -> :mod:`.architecture` (``S2Planner``
-> latent goal + confidence -> ``S1Controller`` -> action, scheduled by
``DualSystemArchitecture``) -> :mod:`.runner` (the same schedule with S2 in a background
thread, S1 never waiting).
"""

from vla_gr.core.dual_system.architecture import (
    DualSystemArchitecture,
    S1Controller,
    S2Planner,
    confidence_targets,
    gate_actions,
    plan_interval,
)
from vla_gr.core.dual_system.config import GATES, DualSystemConfig
from vla_gr.core.dual_system.runner import DualSystemRunner, LatestSlot, Plan

__all__ = [
    "GATES",
    "DualSystemArchitecture",
    "DualSystemConfig",
    "DualSystemRunner",
    "LatestSlot",
    "Plan",
    "S1Controller",
    "S2Planner",
    "confidence_targets",
    "gate_actions",
    "plan_interval",
]
