"""``vla-gr export SRC DST --rename-keys``: a checkpoint written before keys
were renamed gets this version's names with every value unchanged (the shipped agent's
``config.yaml`` as it was before the renames: ``data/vla_gr_cpu_config_before_renames.yaml``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from vla_gr.checkpoint import CheckpointError, read_checkpoint, save_checkpoint
from vla_gr.cli import main as cli_main
from vla_gr.errors import UserError
from vla_gr.policy import load_policy
from vla_gr.policy.export import rename_model_keys
from vla_gr.policy.factory import REMOVED_KEYS, RENAMED_KEYS, checkpoint_model_config

DATA = Path(__file__).parent / "data"
SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"
OLD_YAML = DATA / "vla_gr_cpu_config_before_renames.yaml"


def _leaves(tree, prefix: str = "") -> dict:
    """Dotted key -> value of every leaf of a nested mapping or dataclass tree."""
    if dataclasses.is_dataclass(tree):
        tree = {f.name: getattr(tree, f.name) for f in dataclasses.fields(tree)}
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict) and value or dataclasses.is_dataclass(value):
            out |= _leaves(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


@pytest.fixture(scope="module")
def old_checkpoint(tmp_path_factory) -> Path:
    """The shipped weights with the config they had before the renames."""
    loaded = read_checkpoint(SHIPPED)
    weights = {k: v for k, v in loaded.model.items() if not k.startswith("instruction_reader.")}
    state = {
        "export_overrides": ["navigator.relation_distance=1.0", "s1.kind=pure_pursuit"],
        "filled_defaults": ["navigator.local_cell=0.025", "pursuit.precise_lookahead=0.3"],
    }
    folder = tmp_path_factory.mktemp("old") / "agent"
    return save_checkpoint(folder, 1, weights, state, OLD_YAML.read_text(), links=())


def test_the_old_checkpoint_fails_naming_a_new_key(old_checkpoint, tmp_path, capsys):
    with pytest.raises(CheckpointError, match=r"was renamed model\.\S+; write the new names"):
        load_policy(old_checkpoint)
    assert cli_main(["export", str(old_checkpoint), str(tmp_path / "x")]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.endswith("write the new names with vla-gr export SRC DST --rename-keys")


def test_rename_keys_keeps_every_setting_through_the_mapping(old_checkpoint, tmp_path):
    new = tmp_path / "new"
    # the instruction reader's new keys are not in the old config: filled at their defaults
    assert cli_main(["export", str(old_checkpoint), str(new), "--rename-keys"]) == 2
    args = ["export", str(old_checkpoint), str(new), "--rename-keys", "--fill-missing"]
    assert cli_main(args) == 0
    written = read_checkpoint(new)
    config = checkpoint_model_config(written.config_yaml, new)  # loads: no old key is left
    resolved = _leaves(config)
    old = _leaves(OmegaConf.to_container(OmegaConf.create(OLD_YAML.read_text()).model))
    reached = set()
    for key, value in old.items():
        if key in REMOVED_KEYS:
            continue
        target = RENAMED_KEYS.get(key, key)
        assert resolved[target] == value, f"{key} -> {target}"
        reached.add(target)
    added = {
        f"instruction_reader.{k}"
        for k in ("goal_categories", "temperature", "colors", "intent", "intent_hidden",
                  "min_intent")
    }  # fmt: skip
    added |= {"perception.engine", "navigator.not_found.steps", "navigator.not_found.new_area",
              "navigator.not_found.second_look", "navigator.goal_checks.room_map_keep"}  # fmt: skip
    added |= {
        f"navigator.room_search.{k}"
        for k in ("enabled", "radius", "keep", "categories", "room_types", "presence",
                  "room_share")
    }  # fmt: skip
    assert reached | added == set(resolved)  # every other setting comes from an old one
    # the shipped checkpoint resolves to the same config but for its trained reader, the
    # engine of its perception (ONNX Runtime; the old one ran PyTorch, the default), its
    # room search, the second look of its "not found" and the room map of its room check
    shipped = checkpoint_model_config(read_checkpoint(SHIPPED).config_yaml, SHIPPED)
    assert config.perception.engine == "torch"
    config.instruction_reader = shipped.instruction_reader
    config.perception = shipped.perception
    config.navigator.room_search = shipped.navigator.room_search  # its room_prior stage
    config.navigator.not_found.second_look = shipped.navigator.not_found.second_look  # and so
    config.navigator.goal_checks.room_map_keep = shipped.navigator.goal_checks.room_map_keep
    assert config == shipped
    # the records: what was renamed and dropped; the earlier ones by their new names
    state = written.state
    assert "navigator.confirm_ticks -> navigator.confirmation.ticks" in state["renamed_keys"]
    assert "navigator.pursuit_lookahead -> pursuit.lookahead" in state["renamed_keys"]
    assert len(state["renamed_keys"]) == len(RENAMED_KEYS)
    assert sorted(state["removed_keys"]) == sorted(f"{k}={old[k]}" for k in REMOVED_KEYS)
    assert state["export_overrides"] == [
        "navigator.goal_checks.relation_distance=1.0",
        "s1.kind=pure_pursuit",
    ]
    assert state["filled_defaults"][:2] == [
        "navigator.local_planner.cell=0.025",
        "pursuit.precise_lookahead=0.3",
    ]
    assert {k.split("=")[0] for k in state["filled_defaults"][2:]} == added
    shipped_keys = {k for k in read_checkpoint(SHIPPED).model if not k.startswith("instruction_r")}
    assert written.model.keys() == shipped_keys


def test_renaming_twice_changes_nothing_and_two_keys_that_disagree_are_refused():
    model = OmegaConf.to_container(OmegaConf.create(OLD_YAML.read_text()).model)
    once, renamed, removed = rename_model_keys(model)
    assert len(renamed) == len(RENAMED_KEYS) and len(removed) == len(REMOVED_KEYS)
    assert "dual_system" not in once  # the seed block's section goes with its last key
    assert rename_model_keys(once) == (once, [], [])
    model["navigator"]["pursuit_lookahead"] = 0.7  # the drive test used another lookahead
    with pytest.raises(UserError, match=r"pursuit_lookahead=0\.7 cannot become"):
        rename_model_keys(model)
