"""Export a trained agent for shipping: its weights + config, optional inference settings changed.

    vla-gr export <run>/checkpoints/best checkpoints/vla_gr_cpu navigator.confirmation.ticks=4
    vla-gr export SRC DST --rename-keys   # a checkpoint of older key names, with today's

Writes a verified checkpoint folder (``model.safetensors``, ``config.yaml``,
``trainer_state.json``, ``manifest.json``) without the optimiser / RNG state that only a
resumed training needs. ``key=value`` overrides may change settings no weight depends on
(:data:`~vla_gr.policy.factory.INFERENCE_SETTINGS`: the navigator, its GR field, the S1
follower, the S2 rate); they are validated by loading the result. ``--rename-keys`` migrates a
checkpoint written before keys were renamed (:data:`~vla_gr.policy.factory.RENAMED_KEYS`) or
removed (:data:`~vla_gr.policy.factory.REMOVED_KEYS`): each old key gets its new name, its
value unchanged, and the training state records what was renamed and dropped.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
from collections.abc import Mapping, MutableMapping, Sequence
from pathlib import Path

from vla_gr.checkpoint import MANIFEST_FILE, read_checkpoint, save_checkpoint
from vla_gr.errors import UserError

__all__ = ["export_pretrained", "rename_model_keys", "write_checkpoint_folder"]

_MISSING = object()


def _pop(tree: MutableMapping, key: str):
    """Remove the leaf at dotted ``key`` of ``tree`` and return its value (``_MISSING`` when
    there is none: a section is no leaf); parents it leaves empty go too."""
    *parents, leaf = key.split(".")
    chain = [tree]
    for part in parents:
        node = chain[-1].get(part)
        if not isinstance(node, MutableMapping):
            return _MISSING
        chain.append(node)
    if leaf not in chain[-1] or isinstance(chain[-1][leaf], Mapping):
        return _MISSING
    value = chain[-1].pop(leaf)
    for part, node, parent in zip(reversed(parents), reversed(chain[1:]), reversed(chain[:-1])):
        if node:
            break
        del parent[part]
    return value


def _get(tree: Mapping, key: str):
    """The value at dotted ``key`` of ``tree``, or ``_MISSING``."""
    node = tree
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return _MISSING
        node = node[part]
    return node


def _put(tree: MutableMapping, key: str, value) -> None:
    """Set dotted ``key`` of ``tree`` to ``value`` (sections made as needed)."""
    *parents, leaf = key.split(".")
    for part in parents:
        tree = tree.setdefault(part, {})
    tree[leaf] = value


def rename_model_keys(model: Mapping) -> tuple[dict, list[str], list[str]]:
    """A checkpoint's ``model`` section (nested mapping) with this version's key names: each
    old key of :data:`~vla_gr.policy.factory.RENAMED_KEYS` moved to its new name (its value
    unchanged) and each key of :data:`~vla_gr.policy.factory.REMOVED_KEYS` dropped.

    Returns (the new section, ``"old -> new"`` per renamed key, ``"key=value"`` per dropped
    one). An old key whose new name already holds another value (two keys for one setting
    that disagreed) is a ``UserError``: no value keeps both behaviours.
    """
    from vla_gr.policy.factory import REMOVED_KEYS, RENAMED_KEYS

    tree = copy.deepcopy(dict(model))
    moved = {old: _pop(tree, old) for old in RENAMED_KEYS}
    removed = []
    for key in REMOVED_KEYS:
        value = _pop(tree, key)
        if value is not _MISSING:
            removed.append(f"{key}={value}")
    renamed = []
    for old, value in moved.items():
        if value is _MISSING:
            continue
        new = RENAMED_KEYS[old]
        current = _get(tree, new)
        if current is _MISSING:
            _put(tree, new, value)
        elif current != value:
            raise UserError(
                f"model.{old}={value} cannot become model.{new}, which is {current}: the "
                "checkpoint ran with both; make them equal before renaming"
            )
        renamed.append(f"{old} -> {new}")
    return tree, renamed, removed


def _renamed_setting(item: str) -> str:
    """A ``key=value`` record with the key's new name (unchanged when it was not renamed)."""
    from vla_gr.policy.factory import RENAMED_KEYS

    key, sep, value = item.partition("=")
    return f"{RENAMED_KEYS.get(key.strip(), key)}{sep}{value}"


def _in_order(tree: Mapping, schema: Mapping) -> dict:
    """``tree`` with its keys in the order of ``schema`` (keys it lacks last), recursively."""
    keys = [k for k in schema if k in tree] + [k for k in tree if k not in schema]
    return {
        k: _in_order(tree[k], schema[k])
        if isinstance(tree[k], Mapping) and isinstance(schema.get(k), Mapping)
        else tree[k]
        for k in keys
    }


def export_pretrained(
    src: str | Path,
    dst: str | Path,
    overrides: Sequence[str] = (),
    fill_missing: bool = False,
    rename_keys: bool = False,
) -> Path:
    """Copy checkpoint ``src`` to folder ``dst`` (replaced) with ``overrides`` applied; its
    training state lists every override of ``src``'s exports and these (``export_overrides``).

    ``fill_missing``: a checkpoint written before some model keys existed gets each missing
    key written with this version's default (listed in its state as ``filled_defaults``);
    the loader never fills them itself, so use it only where those defaults are the values
    the checkpoint was run with.

    ``rename_keys``: a checkpoint written before keys were renamed or removed gets this
    version's names (:func:`rename_model_keys`: values unchanged, keys in the schema's
    order); its state records them (``renamed_keys``, ``removed_keys``) and its earlier
    records (``export_overrides``, ``filled_defaults``) name the settings by their new names.
    """
    from omegaconf import OmegaConf

    from vla_gr.configs.model_schema import ModelConfig
    from vla_gr.policy.factory import checkpoint_model_config, load_policy, model_key_gaps

    dst = Path(dst)
    loaded = read_checkpoint(src)
    config = OmegaConf.create(loaded.config_yaml)
    state = loaded.state
    updates: dict = {}
    if rename_keys:
        schema = OmegaConf.to_container(OmegaConf.structured(ModelConfig))
        model, renamed, removed = rename_model_keys(OmegaConf.to_container(config.model))
        config.model = OmegaConf.create(_in_order(model, schema))
        for record, items in (("renamed_keys", renamed), ("removed_keys", removed)):
            if items:
                updates[record] = list(state.get(record, [])) + items
        for record in ("export_overrides", "filled_defaults"):
            if record in state:
                updates[record] = [_renamed_setting(item) for item in state[record]]
    filled: list[str] = []
    if fill_missing:
        defaults = OmegaConf.structured(ModelConfig)
        missing, _ = model_key_gaps(OmegaConf.to_container(config.model))
        for key in missing:
            value = OmegaConf.select(defaults, key)
            OmegaConf.update(config.model, key, value, force_add=True)
            filled.append(f"{key}={value}")
    if fill_missing or rename_keys:  # checks the new config and the overrides
        checkpoint_model_config(OmegaConf.to_yaml(config), src, overrides)
    else:  # checks the overrides, then src's weights (an ONNX export is written below)
        checkpoint_model_config(loaded.config_yaml, src, overrides, loaded.config_file)
        load_policy(src, overrides=[*overrides, "perception.engine=torch"])
    model = OmegaConf.merge(config.model, OmegaConf.from_dotlist(list(overrides)))
    config.model = model
    # the overrides accumulate over exports; re-exporting in place keeps the first origin
    in_place = Path(src).resolve() == dst.resolve()
    origin = state.get("exported_from", str(src)) if in_place else str(src)
    earlier = list(updates.get("export_overrides", state.get("export_overrides", [])))
    updates |= {"exported_from": origin, "export_overrides": earlier + list(overrides)}
    if filled:
        earlier_filled = updates.get("filled_defaults", state.get("filled_defaults", []))
        updates["filled_defaults"] = list(earlier_filled) + filled
    return write_checkpoint_folder(dst, loaded, loaded.model, OmegaConf.to_yaml(config), updates)


def write_checkpoint_folder(
    dst: str | Path, loaded, tensors: Mapping, config_yaml: str, state_updates: Mapping
) -> Path:
    """Write ``tensors`` and ``config_yaml`` as checkpoint folder ``dst`` (replaced once the
    new one is complete), with the training state of checkpoint ``loaded`` (without its RNG,
    at its step) plus ``state_updates``, and the ONNX export of its perception networks when
    ``model.perception.engine=onnxruntime`` (:mod:`vla_gr.policy.onnx_export`); verified by
    loading the result. Files of an existing ``dst`` that its manifest does not list (its
    ``eval_results.md``) are carried over."""
    from omegaconf import OmegaConf

    from vla_gr.policy.factory import load_policy
    from vla_gr.policy.onnx_export import export_onnx

    dst = Path(dst)
    staging = dst.parent / f".export-{dst.name}-{os.getpid()}"
    if staging.exists():
        shutil.rmtree(staging)
    state = {k: v for k, v in loaded.state.items() if k != "rng"}
    state.update(state_updates)
    written = save_checkpoint(
        staging, int(loaded.state.get("step", 0)), tensors, state, config_yaml, links=()
    )
    if OmegaConf.select(OmegaConf.create(config_yaml), "model.perception.engine") == "onnxruntime":
        export_onnx(written)
    if dst.exists():
        listed = _listed_files(dst)
        for kept in sorted(dst.iterdir()):
            if kept.is_file() and kept.name not in listed and not (written / kept.name).exists():
                shutil.copy2(kept, written / kept.name)
        shutil.rmtree(dst)
    os.replace(written, dst)
    shutil.rmtree(staging)
    load_policy(dst)  # the result verifies and loads
    return dst


def _listed_files(folder: Path) -> set[str]:
    """The files the manifest of checkpoint ``folder`` lists (none without a readable one)."""
    try:
        return set(json.loads((folder / MANIFEST_FILE).read_text())["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return set()
