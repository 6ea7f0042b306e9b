"""Room search: room evidence spreads through free space only, a cell's value is the room
prior under its room posterior, and the section is checked."""

from __future__ import annotations

import numpy as np
import pytest

from vla_gr.agent.navigator.config import NavigatorConfig, RoomSearchConfig
from vla_gr.agent.navigator.room_search import RoomSearch
from vla_gr.training.room_prior import room_search_overrides

ROOMS = ["kitchen", "bathroom"]


def _search(**settings) -> RoomSearch:
    config = RoomSearchConfig(
        enabled=True, categories=["toilet", "chair"], room_types=ROOMS,
        presence=[[0.1, 0.9], [0.8, 0.2]], room_share=[0.75, 0.25], **settings,
    )  # fmt: skip
    return RoomSearch(config, (20, 20), cell_size=0.1)


def test_room_evidence_spreads_through_free_space_up_to_the_radius_and_not_through_walls():
    search = _search(radius=0.5)
    free = np.ones((20, 20), bool)
    free[:, 8] = False  # a wall along column 8
    search.observe(np.array([1.0, 0.0]), (10, 5), free)
    typed = search.count > 0
    assert typed[10, 5] and typed[10, 7] and typed[5, 5] and not typed[4, 5]  # 5 cells up
    assert not typed[:, 8:].any()  # the wall stops it
    search.observe(np.array([0.0, 1.0]), (10, 5), free)
    np.testing.assert_allclose(search.evidence[:, 10, 5] / search.count[10, 5], [0.5, 0.5])


def test_a_cell_is_worth_the_prior_under_its_room_posterior():
    search = _search(radius=0.2)
    assert search.value() is None  # no goal yet: every cell alike
    search.set_goal("toilet", None)
    free = np.ones((20, 20), bool)
    search.observe(np.array([0.8, 0.2]), (3, 3), free)
    value = search.value()
    assert value[3, 3] == pytest.approx(0.8 * 0.1 + 0.2 * 0.9)
    assert value[15, 15] == pytest.approx(0.75 * 0.1 + 0.25 * 0.9)  # an untyped cell
    search.set_goal("toilet", "kitchen")  # a named room: only a kitchen is worth searching
    assert search.value()[3, 3] == pytest.approx(0.8 * 0.1)
    assert search.value()[15, 15] == pytest.approx(0.75 * 0.1)
    search.set_goal("piano", None)  # no learned presence: every cell alike
    assert search.value() is None


def test_the_room_belief_of_a_cell_is_the_mean_of_the_instructed_rooms_evidence_there():
    search = _search(radius=0.2)
    free = np.ones((20, 20), bool)
    search.observe(np.array([0.8, 0.2]), (3, 3), free)
    search.observe(np.array([0.4, 0.6]), (3, 3), free)
    assert search.room_belief((3, 3)) is None  # no goal: no instructed room
    search.set_goal("toilet", None)
    assert search.room_belief((3, 3)) is None  # a goal without a room
    search.set_goal("toilet", "bathroom")
    assert search.room_belief((3, 3)) == pytest.approx(0.4)  # (0.2 + 0.6) / 2
    search.set_goal("chair", "kitchen")
    assert search.room_belief((3, 3)) == pytest.approx(0.6)
    assert search.room_belief((15, 15)) is None  # no tick typed it
    assert search.room_belief((25, 3)) is None  # off the map
    search.set_goal("chair", "garage")  # a room type the classifier has not: nothing to judge
    assert search.room_belief((3, 3)) is None


def test_the_section_is_checked_and_the_overrides_name_its_keys():
    with pytest.raises(ValueError, match="room_search.keep"):
        RoomSearchConfig(keep=1.5)
    with pytest.raises(ValueError, match="a value per room type"):
        RoomSearchConfig(room_types=ROOMS, room_share=[1.0])
    with pytest.raises(ValueError, match="a row per category"):
        RoomSearchConfig(categories=["bed"], room_types=ROOMS, room_share=[0.5, 0.5])
    with pytest.raises(ValueError, match="python -m vla_gr.training.room_prior"):
        RoomSearchConfig(enabled=True)
    assert NavigatorConfig().room_search.enabled is False  # off unless a checkpoint says so
    prior = {"categories": ["bed", "sofa"], "room_types": ROOMS,
             "presence": [[0.1, 0.9], [0.2, 0.3]], "room_share": [0.5, 0.5]}  # fmt: skip
    overrides = room_search_overrides(prior, keep=0.4)
    assert overrides == [
        "navigator.room_search.enabled=true",
        "navigator.room_search.categories=[bed,sofa]",
        "navigator.room_search.room_types=[kitchen,bathroom]",
        "navigator.room_search.presence=[[0.1,0.9],[0.2,0.3]]",
        "navigator.room_search.room_share=[0.5,0.5]",
        "navigator.room_search.keep=0.4",
    ]
    from omegaconf import OmegaConf

    merged = OmegaConf.merge(
        OmegaConf.structured(NavigatorConfig),
        OmegaConf.from_dotlist([o.split(".", 1)[1] for o in overrides]),
    )
    section = OmegaConf.to_object(merged).room_search  # the overrides make a valid section
    assert section.presence == [[0.1, 0.9], [0.2, 0.3]] and section.keep == 0.4
