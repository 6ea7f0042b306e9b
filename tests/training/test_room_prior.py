"""The room prior of room search: counted from houses (and changing with them), and written
into an agent by a ``room_prior`` stage."""

from __future__ import annotations

from types import SimpleNamespace

from vla_gr.training.room_prior import fit_room_prior

ROOMS = ["kitchen", "bathroom"]


def _house(*rooms):
    """A house of (room type, categories in it) pairs."""
    return SimpleNamespace(
        rooms=[SimpleNamespace(index=k, room_type=t) for k, (t, _) in enumerate(rooms)],
        objects=[
            SimpleNamespace(category=c, room_index=k)
            for k, (_, held) in enumerate(rooms)
            for c in held
        ],
    )


def test_the_prior_is_counted_from_the_houses_with_a_beta_1_1_prior():
    houses = [
        _house(("kitchen", ["chair", "chair"]), ("bathroom", ["toilet"])),
        _house(("kitchen", []), ("bathroom", ["toilet", "plant"])),
        _house(("kitchen", ["chair", "plant"])),
    ]
    made = iter(houses)
    prior = fit_room_prior(3, categories=["chair", "toilet", "plant"], room_types=ROOMS,
                           generate=lambda seed, rooms: next(made))  # fmt: skip
    # kitchens: 3, two with a chair; bathrooms: 2, both with a toilet, one with a plant
    assert prior["categories"] == ["chair", "toilet", "plant"]
    assert prior["presence"] == [
        [round(3 / 5, 4), round(1 / 4, 4)],  # chair
        [round(1 / 5, 4), round(3 / 4, 4)],  # toilet
        [round(2 / 5, 4), round(2 / 4, 4)],  # plant
    ]
    assert prior["room_share"] == [0.6, 0.4] and prior["rooms"] == 5


def test_the_world_s_prior_changes_with_its_houses():
    train = fit_room_prior(60)
    other = fit_room_prior(60, split="val")
    assert train["presence"] != other["presence"]  # counted, not a table
    toilet = dict(zip(train["room_types"], train["presence"][train["categories"].index("toilet")]))
    assert max(toilet, key=toilet.get) == "bathroom"  # what the generator does, learned


def test_a_room_prior_stage_writes_the_agent_with_room_search_on(tiny_agent, tmp_path):
    from omegaconf import OmegaConf

    from vla_gr.checkpoint import read_checkpoint
    from vla_gr.configs import load_config
    from vla_gr.configs.pipeline_schema import StageConfig
    from vla_gr.policy import load_policy
    from vla_gr.training.stages import STAGES

    _, cfg = load_config("config_debug", ["training.room_prior.houses=12"])
    stage = StageConfig(name="rooms", kind="room_prior", inputs=["agent"],
                        model_overrides=["navigator.room_search.keep=0.4"])  # fmt: skip
    out = STAGES["room_prior"](stage, cfg, None, tmp_path, {"agent": tiny_agent}, None)
    written = read_checkpoint(out)
    section = OmegaConf.create(written.config_yaml).model.navigator.room_search
    prior = fit_room_prior(12)
    assert section.enabled and section.keep == 0.4
    assert OmegaConf.to_container(section.presence) == prior["presence"]
    assert list(section.room_share) == prior["room_share"]
    init = read_checkpoint(tiny_agent)
    assert written.model.keys() == init.model.keys()  # weights untouched
    policy = load_policy(out)  # and it loads, the navigator's search on
    assert policy.config.navigator.room_search.enabled
