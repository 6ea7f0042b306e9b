"""``recipe_vla_gr_cpu`` (how the shipped checkpoint was made, as stages) ends in exactly the
model settings ``checkpoints/vla_gr_cpu`` carries: the recipe's model config with what each
stage writes into the agent (the checks it trains, S1's kind, the export overrides)."""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf

from vla_gr.checkpoint import read_checkpoint
from vla_gr.configs import load_config
from vla_gr.training.pipeline import stage_config
from vla_gr.training.room_prior import fit_room_prior, room_search_overrides

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"


def _leaves(tree: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict) and value:
            out |= _leaves(value, f"{prefix}{key}.")
        else:
            out[prefix + key] = value
    return out


def test_the_shipped_recipe_ends_in_the_shipped_checkpoints_model_settings():
    resolved, cfg = load_config("recipe_vla_gr_cpu", [])
    written: list[str] = []  # what the stages write into the agent's config, in order
    for stage in cfg.pipeline.stages:
        _, stage_cfg = stage_config(resolved, stage)  # every stage's config is valid
        if stage.kind == "room_type":
            threshold = stage_cfg.training.room_type.reject_threshold
            written += ["room_type.enabled=true",
                        f"navigator.goal_checks.room_reject_threshold={threshold}"]  # fmt: skip
        elif stage.kind == "object_category":
            threshold = stage_cfg.training.object_category.reject_threshold
            written += ["object_category.enabled=true",
                        f"navigator.goal_checks.object_reject_threshold={threshold}"]  # fmt: skip
        elif stage.kind == "graft":
            written += [f"{stage.part}.enabled=true", *stage.model_overrides]
        elif stage.kind == "s1":
            written.append("s1.kind=learned")
        elif stage.kind == "export":
            written += list(stage.model_overrides)
        elif stage.kind == "instruction_reader":
            written += ["instruction_reader.enabled=true",
                        *stage_cfg.training.instruction_reader.settings]  # fmt: skip
        elif stage.kind == "request_intent":
            written.append("instruction_reader.intent=true")
        elif stage.kind == "room_prior":  # the prior counted again from the same houses
            r = stage_cfg.training.room_prior
            written += [*room_search_overrides(fit_room_prior(r.houses, r.split)),
                        *stage.model_overrides]  # fmt: skip
    model = OmegaConf.merge(
        OmegaConf.to_container(resolved.model, resolve=True), OmegaConf.from_dotlist(written)
    )
    loaded = read_checkpoint(SHIPPED)
    shipped = OmegaConf.create(loaded.config_yaml).model
    rebuilt = _leaves(OmegaConf.to_container(model, resolve=True))
    want = _leaves(OmegaConf.to_container(shipped, resolve=True))
    # the reader's temperature and threshold are chosen by its stage on the development sets:
    # the shipped values are the ones its training state records
    chosen = loaded.state["instruction_reader_training"]["development"]
    for key in ("temperature", "min_confidence"):
        assert want.pop(f"instruction_reader.{key}") == chosen[key]
        rebuilt.pop(f"instruction_reader.{key}")
    # and min_intent by the intent stage
    intent = loaded.state["request_intent_training"]["development"]["min_intent"]
    assert want.pop("instruction_reader.min_intent") == intent
    rebuilt.pop("instruction_reader.min_intent")
    assert {k: (rebuilt.get(k), want.get(k)) for k in rebuilt.keys() | want.keys()
            if rebuilt.get(k) != want.get(k)} == {}  # fmt: skip
    assert [s.name for s in cfg.pipeline.stages][-1] == "shipped" and len(cfg.pipeline.stages) == 35
