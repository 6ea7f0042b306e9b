"""The dual system declares ``not_found`` when its navigator's plan says the reachable house is
searched: that step and every later one returns no motion and no STOP; reset() clears it."""

from __future__ import annotations

import numpy as np

from tests.policy.test_dual_system_agent import _model, _obs
from vla_gr.agent.navigator import NavPlan


def test_a_plan_that_says_not_found_is_declared_and_not_acted_on():
    model = _model()
    system = model.dual_system
    ticks = []

    def plan(*args, **kwargs) -> NavPlan:  # S2's tick: the house is searched on the third
        ticks.append(1)
        waypoints = np.array([[1.0, 0.0], [2.0, 0.0]])
        return NavPlan(waypoints, "explore", 0.0, False, not_found=len(ticks) >= 3)

    system.navigator.plan = plan
    model.reset()
    every = system.plan_every
    actions = [model.select_action(_obs()) for _ in range(2 * every)]  # two S2 ticks
    assert all(a[2] <= 0 for a in actions) and actions[0][0] > 0  # it drove, never stopped
    assert model.declared_outcome is None and len(ticks) == 2
    action = model.select_action(_obs())  # the third tick says "not found"
    assert action.tolist() == [0.0, 0.0, 0.0] and model.declared_outcome == "not_found"
    for _ in range(4):  # asked again, it stays declared and plans no more
        assert model.select_action(_obs()).tolist() == [0.0, 0.0, 0.0]
    assert model.declared_outcome == "not_found" and len(ticks) == 3
    model.reset()
    assert model.declared_outcome is None
