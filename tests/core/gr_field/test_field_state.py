"""GRField's own state behind its methods: typed maps, the planning radius, map edits."""

import dataclasses

import numpy as np
import pytest
import torch

from tests.agent.navigator.navigator_scenes import make_nav, room_depth, tick
from vla_gr.core.gr_field import FieldMaps, GRField, GRFieldConfig
from vla_gr.core.gr_field.mapping import (
    FREE_HITS,
    GOAL_SUM,
    OCC_HITS,
    POINT_HITS,
    forget_noise,
    mark_unseen_free,
)
from vla_gr.core.gr_field.physics import conformal_log_factor, solve_poisson


def obs_of(*poses):
    """Box-room depth (B, n, n, 1) and poses (B, 3) of the navigator's scenes."""
    depth = np.stack([room_depth(p) for p in poses])  # (B, n, n, 1)
    return {"depth": torch.from_numpy(depth), "pose": torch.tensor(poses, dtype=torch.float32)}


def small_field(**overrides) -> GRField:
    return GRField(GRFieldConfig(map_size=64, cell_size=0.15, ego_size=16, **overrides))


def test_field_maps_carry_the_documented_shapes_and_are_read_only():
    field = small_field()
    with pytest.raises(RuntimeError, match="prior update"):
        _ = field.maps
    field.update(obs_of((0.0, 0.0, 0.0), (0.5, -0.3, 1.0)))
    maps = field.maps
    assert isinstance(maps, FieldMaps) and field.maps is maps
    for name in ("psi", "travel", "rho"):
        assert getattr(maps, name).shape == (2, 64, 64) and getattr(maps, name).is_floating_point()
    for name in ("occupied", "explored", "frontier", "goal"):
        assert getattr(maps, name).shape == (2, 64, 64) and getattr(maps, name).dtype == torch.bool
    assert maps.robot_xy.shape == (2, 2) and maps.yaw.shape == (2,)
    assert maps.has_path.shape == (2,) and maps.has_path.dtype == torch.bool
    assert maps.robot_xy[1].tolist() == pytest.approx([0.5 + 4.8, -0.3 + 4.8])  # from the corner
    with pytest.raises(dataclasses.FrozenInstanceError):
        maps.psi = torch.zeros(2, 64, 64)
    # phi_hat: the full potential of rho rescaled to [0, 1], solved once on first read
    assert "phi_hat" not in vars(maps)
    phi = solve_poisson(maps.rho, 0.15, GRFieldConfig().G)  # (2, 64, 64)
    expected = conformal_log_factor(phi, torch.zeros_like(phi), 1.0, 0.0)  # (2, 64, 64)
    assert torch.equal(maps.phi_hat, expected) and maps.phi_hat is maps.phi_hat
    assert float(maps.phi_hat.min()) >= 0.0 and float(maps.phi_hat.max()) <= 1.0
    # a layer of another shape is refused on construction
    parts = {f.name: getattr(maps, f.name) for f in dataclasses.fields(FieldMaps)}
    with pytest.raises(ValueError, match="travel"):
        FieldMaps(**{**parts, "travel": maps.travel[:, :-1]})
    with pytest.raises(ValueError, match="robot_xy"):
        FieldMaps(**{**parts, "robot_xy": maps.robot_xy[:1]})


def test_the_planning_radius_is_used_by_the_next_update_and_restored_without_the_config():
    obs = obs_of((2.3, 1.3, 0.5))  # near a corner of the room: walls on two sides
    ref, thin = small_field(), small_field()
    assert thin.planning_radius == thin.config.robot_radius == 0.18
    ref.update(obs)
    thin.update(obs)
    thin.set_planning_radius(0.05)
    assert thin.planning_radius == 0.05 and thin.config.robot_radius == 0.18  # config untouched
    ref_out, thin_out = ref.update(obs), thin.update(obs)
    # a thinner robot fits nearer the walls: more cells reachable, the same walls
    reach_ref = int(torch.isfinite(ref.maps.travel).sum())
    reach_thin = int(torch.isfinite(thin.maps.travel).sum())
    assert reach_thin > reach_ref and torch.equal(thin.maps.occupied, ref.maps.occupied)
    assert not torch.equal(thin_out.distance, ref_out.distance)
    thin.set_planning_radius(0.18)  # restored: the next update plans as the reference again
    ref_out, thin_out = ref.update(obs), thin.update(obs)
    assert torch.equal(thin.maps.travel, ref.maps.travel)
    assert torch.equal(thin_out.waypoints, ref_out.waypoints)
    thin.reset()
    assert thin.planning_radius == 0.18  # a reset keeps whatever radius was set
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="planning radius"):
            thin.set_planning_radius(bad)


def test_the_navigator_plans_thinner_through_the_field_and_never_writes_its_config():
    nav = make_nav(look_around={"angle": 0.0}, tight={"steps": 2, "radius": 0.05})
    config = dataclasses.replace(nav.field.config)
    tick(nav, (0.0, 0.0, 0.0))
    nav._start_tight()
    assert nav.field.planning_radius == 0.05
    tick(nav, (0.0, 0.0, 0.0))
    assert nav.field.planning_radius == 0.05  # one tight tick left
    tick(nav, (0.0, 0.0, 0.0))
    assert nav.field.planning_radius == 0.18
    nav._start_tight()
    nav.reset()  # a new episode plans at the configured radius again
    assert nav.field.planning_radius == 0.18 and nav.field.config == config


def test_forget_noise_zeroes_exactly_the_outvoted_obstacle_cells():
    state = torch.zeros(4, 2, 5)  # (4, H, W)
    state[OCC_HITS, 0] = torch.tensor([1.0, 2.0, 2.0, 3.0, 0.0])
    state[FREE_HITS, 0] = torch.tensor([4.0, 8.0, 7.0, 100.0, 9.0])
    state[GOAL_SUM], state[POINT_HITS] = 0.5, 2.0
    before = state.clone()
    forget_noise(state, max_hits=2.0, free_ratio=4.0)
    changed = (state != before).nonzero().tolist()  # [[channel, row, col], ...]
    assert changed == [[OCC_HITS, 0, 0], [OCC_HITS, 0, 1]]
    assert state[OCC_HITS, 0, 0] == 0.0 and state[OCC_HITS, 0, 1] == 0.0


def test_mark_unseen_free_adds_one_free_hit_to_exactly_the_unseen_cells():
    state = torch.zeros(4, 3, 3)  # (4, H, W)
    state[OCC_HITS, 0, 0] = 2.0  # seen occupied
    state[POINT_HITS, 1, 1] = 1.0  # seen, no obstacle
    cells = torch.tensor([[0, 0], [1, 1], [2, 2], [0, 2], [2, 2]])  # (D, 2), (2, 2) twice
    before = state.clone()
    mark_unseen_free(state, cells)
    changed = (state != before).nonzero().tolist()
    assert changed == [[FREE_HITS, 0, 2], [FREE_HITS, 2, 2]]
    assert state[FREE_HITS, 2, 2] == 1.0  # listed twice, one hit


def test_the_fields_edit_methods_change_only_the_given_map_and_evidence_is_a_copy():
    field = small_field(clearance_factor=3)
    with pytest.raises(ValueError, match="no map 0"):
        field.mark_unseen_free(torch.tensor([[5, 5]]))
    assert field.batch_size == 0
    field.update(obs_of((0.0, 0.0, 0.0), (0.5, 0.2, 2.0)))
    assert field.batch_size == 2 and field.cell_size == 0.15
    with pytest.raises(ValueError, match="no map 2"):
        field.evidence(2)
    before = [field.evidence(0), field.evidence(1)]  # (4, H, W) each
    sub_before = field.sub_hits.clone()
    copy = field.evidence(1)
    copy += 7.0  # a copy: the field's map is not written
    assert torch.equal(field.evidence(1), before[1])
    # unseen cells (outside the room) and one seen cell of map 1
    seen = tuple(int(v) for v in (before[1].sum(0) > 0).nonzero()[0])  # (row, col)
    field.mark_unseen_free(torch.tensor([[2, 3], [4, 5], list(seen)]), index=1)
    diff = field.evidence(1) - before[1]  # (4, H, W)
    assert diff.nonzero().tolist() == [[FREE_HITS, 2, 3], [FREE_HITS, 4, 5]]
    assert torch.equal(field.evidence(0), before[0])
    # noise: the field applies forget_noise to map 1 alone, sub-cell counts stay
    field.add_obstacle_evidence(torch.tensor([[2, 3]]), 1.0, index=1)  # 1 point, 1 free hit
    expected = field.evidence(1)
    forget_noise(expected, max_hits=2.0, free_ratio=1.0)
    assert expected[OCC_HITS, 2, 3] == 0.0
    sub_marked = field.sub_hits.clone()
    field.forget_obstacle_noise(2.0, 1.0, index=1)
    assert torch.equal(field.evidence(1), expected) and torch.equal(field.evidence(0), before[0])
    assert torch.equal(field.sub_hits, sub_marked) and not torch.equal(sub_marked, sub_before)
