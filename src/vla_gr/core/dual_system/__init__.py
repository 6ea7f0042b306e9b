"""Dual system: a slow planner S2 steering a fast reactive controller S1.

Data flow: :mod:`.config` (``DualSystemConfig``) -> :mod:`.planner` (``S2Planner``: latent
goal + confidence) -> :mod:`.controller` (``S1Controller``: action) -> :mod:`.architecture`
(``DualSystemArchitecture``: S2 every few S1 calls) -> :mod:`.runner` (the same schedule
with S2 in a background thread, S1 never waiting).
"""

from vla_gr.core.dual_system.architecture import (
    DualSystemArchitecture,
    confidence_targets,
    plan_interval,
)
from vla_gr.core.dual_system.config import GATES, DualSystemConfig
from vla_gr.core.dual_system.controller import S1Controller, gate_actions
from vla_gr.core.dual_system.planner import S2Planner
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
