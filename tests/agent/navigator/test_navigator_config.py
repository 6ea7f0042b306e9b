"""The navigator's settings, one section per concern: each section validates its values naming
the full key, and each collaborator is built from its own section only."""

import dataclasses

import numpy as np
import pytest
import torch

from tests.agent.navigator.navigator_scenes import LOOKAHEAD, tick
from vla_gr.agent.navigator import Navigator
from vla_gr.agent.navigator.config import (
    ApproachConfig,
    ConfirmationConfig,
    GoalChecksConfig,
    LocalPlannerConfig,
    LookAroundConfig,
    MapEditsConfig,
    NavigatorConfig,
    RecoveryConfig,
    TightConfig,
    TrapsConfig,
)
from vla_gr.agent.navigator.goal_checks import GoalChecks
from vla_gr.agent.navigator.local_planner import LocalPlanner
from vla_gr.agent.navigator.map_edits import MapEdits
from vla_gr.core.gr_field import GRField, GRFieldConfig
from vla_gr.core.gr_field.mapping import OCC_HITS


@pytest.mark.parametrize(
    "section, key, value",
    [
        (LookAroundConfig, "angle", -1.0),
        (ConfirmationConfig, "ticks", 0),
        (ConfirmationConfig, "pixel_threshold", 0.0),
        (ConfirmationConfig, "visible_threshold", 1.5),
        (GoalChecksConfig, "room_reject_threshold", -0.1),
        (ApproachConfig, "stop_distance_at_end", -0.5),
        (ApproachConfig, "verify_steps", 0),
        (ApproachConfig, "unreachable_steps", -1),
        (RecoveryConfig, "back_speed", 1.5),
        (RecoveryConfig, "blocked_steps", 0),
        (TrapsConfig, "radius", -0.1),
        (TightConfig, "speed", 0.0),
        (LocalPlannerConfig, "off_path", -0.1),
        (MapEditsConfig, "obstacle_hits", -1.0),
    ],
)
def test_a_section_rejects_a_bad_value_naming_its_full_key(section, key, value):
    name = next(f.name for f in dataclasses.fields(NavigatorConfig) if f.default_factory is section)
    with pytest.raises(ValueError, match=rf"^model\.navigator\.{name}\.{key}={value} must be"):
        section(**{key: value})
    with pytest.raises(ValueError, match=r"^model\.navigator\.turn_rate=0\.0 must be in \(0, 1\]"):
        NavigatorConfig(turn_rate=0.0)


def test_a_bad_value_in_a_recipe_names_its_full_key():
    from vla_gr.configs import ConfigError, load_config

    with pytest.raises(ConfigError, match=r"model\.navigator\.recovery\.stuck_steps=0"):
        load_config("config_debug", ["model.navigator.recovery.stuck_steps=0"])


def test_the_navigator_hands_each_collaborator_its_own_section():
    config = NavigatorConfig(local_planner=LocalPlannerConfig(enabled=True))
    nav = Navigator(config, GRFieldConfig(map_size=64, cell_size=0.15), lookahead=LOOKAHEAD)
    assert nav.local.config is config.local_planner
    assert nav.map_edits.config is config.map_edits
    assert nav.checks.config is config.goal_checks
    assert nav.checks.confirm_ticks == config.confirmation.ticks
    assert nav.lookahead == LOOKAHEAD  # the follower's, handed in: no key of its own


def test_each_collaborator_works_from_its_section_alone():
    fcfg = GRFieldConfig(map_size=64, cell_size=0.15, ego_size=16)
    field = GRField(fcfg)
    nav = Navigator(NavigatorConfig(), fcfg, lookahead=LOOKAHEAD)
    tick(nav, (0.0, 0.0, 0.0))  # a field with maps, for the map edits below
    # map edits: its section's evidence count marks an obstacle
    edits = MapEdits(nav.field, MapEditsConfig(obstacle_hits=7.0))
    edits.mark_obstacle(np.array([1.0, 0.0]), 0.1)
    cells = edits.virtual[0]  # (D, 2)
    assert float(nav.field.evidence()[OCC_HITS][cells[0, 0], cells[0, 1]]) >= 7.0
    edits.mark_visited(np.array([0.0, 0.0]))
    # goal checks: its section and the confirmation's tick count, nothing else
    checks = GoalChecks(GoalChecksConfig(room_reject_threshold=0.5, room_ticks=2), 3, (8, 8), 0.15)
    checks.observe(0.1, None)
    assert checks.wrong_room()
    votes = np.zeros((8, 8), np.int32)
    votes[2, 2] = 3
    assert checks.confirmed_goal(votes).sum() == 1
    # the local planner: its section sizes the fine cells and the robot's margin
    planner = LocalPlanner(field.grid, 0.18, LocalPlannerConfig(cell=0.05, margin=0.03), 0.1, 1.2)
    assert planner.k == 3 and planner.radius == pytest.approx(0.21)
    planner.observe(torch.zeros(1, 1, 3), torch.zeros(1, 1, dtype=torch.bool))
