"""Dual system: a slow planner S2 steering a fast reactive controller S1.

Data flow: :mod:`.config` (``DualSystemConfig``; the agent's ``ScheduleConfig`` and
``S1Config``) -> :mod:`.planner` (``S2Planner``: latent goal + confidence) -> :mod:`.controller`
(``S1Controller``: action) -> :mod:`.architecture` (``DualSystemArchitecture``: S2 every few S1
calls) -> :mod:`.runner` (the same schedule with S2 in a background thread, S1 never waiting).
The VLA-GR agent's own S1 followers (pure pursuit, the learned S1) are
:mod:`vla_gr.agent.followers`.
"""

from vla_gr.core.dual_system.architecture import (
    DualSystemArchitecture,
    confidence_targets,
    plan_interval,
)
from vla_gr.core.dual_system.config import (
    GATES,
    S1_KINDS,
    DualSystemConfig,
    S1Config,
    ScheduleConfig,
)
from vla_gr.core.dual_system.controller import S1Controller, gate_actions
from vla_gr.core.dual_system.planner import S2Planner
from vla_gr.core.dual_system.runner import DualSystemRunner, LatestSlot, Plan

__all__ = [
    "GATES",
    "S1_KINDS",
    "DualSystemArchitecture",
    "DualSystemConfig",
    "DualSystemRunner",
    "LatestSlot",
    "Plan",
    "S1Config",
    "S1Controller",
    "S2Planner",
    "ScheduleConfig",
    "confidence_targets",
    "gate_actions",
    "plan_interval",
]
