"""Export a trained agent for shipping: its weights + config, optional inference settings changed.

    vla-gr export <run>/checkpoints/best checkpoints/vla_gr_cpu navigator.confirm_ticks=4

Writes a verified checkpoint folder (``model.safetensors``, ``config.yaml``,
``trainer_state.json``, ``manifest.json``) without the optimiser / RNG state that only a
resumed training needs. ``key=value`` overrides may change settings no weight depends on
(:data:`~vla_gr.policy.factory.INFERENCE_SETTINGS`: the navigator, its GR field, the S1
follower, the S2 rate); they are validated by loading the result.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path

from vla_gr.checkpoint import read_checkpoint, save_checkpoint

__all__ = ["export_pretrained", "write_checkpoint_folder"]


def export_pretrained(
    src: str | Path, dst: str | Path, overrides: Sequence[str] = (), fill_missing: bool = False
) -> Path:
    """Copy checkpoint ``src`` to folder ``dst`` (replaced) with ``overrides`` applied; its
    training state lists every override of ``src``'s exports and these (``export_overrides``).

    ``fill_missing``: a checkpoint written before some model keys existed gets each missing
    key written with this version's default (listed in its state as ``filled_defaults``);
    the loader never fills them itself, so use it only where those defaults are the values
    the checkpoint was run with.
    """
    from omegaconf import OmegaConf

    from vla_gr.configs.model_schema import ModelConfig
    from vla_gr.policy.factory import load_policy, model_key_gaps

    dst = Path(dst)
    loaded = read_checkpoint(src)
    config = OmegaConf.create(loaded.config_yaml)
    filled: list[str] = []
    if fill_missing:
        defaults = OmegaConf.structured(ModelConfig)
        missing, _ = model_key_gaps(OmegaConf.to_container(config.model))
        for key in missing:
            value = OmegaConf.select(defaults, key)
            OmegaConf.update(config.model, key, value, force_add=True)
            filled.append(f"{key}={value}")
    else:
        load_policy(src, overrides=overrides)  # checks src and the overrides
    model = OmegaConf.merge(config.model, OmegaConf.from_dotlist(list(overrides)))
    config.model = model
    # the overrides accumulate over exports; re-exporting in place keeps the first origin
    in_place = Path(src).resolve() == dst.resolve()
    origin = loaded.state.get("exported_from", str(src)) if in_place else str(src)
    earlier = list(loaded.state.get("export_overrides", []))
    updates = {"exported_from": origin, "export_overrides": earlier + list(overrides)}
    if filled:
        updates["filled_defaults"] = list(loaded.state.get("filled_defaults", [])) + filled
    return write_checkpoint_folder(dst, loaded, loaded.model, OmegaConf.to_yaml(config), updates)


def write_checkpoint_folder(
    dst: str | Path, loaded, tensors: Mapping, config_yaml: str, state_updates: Mapping
) -> Path:
    """Write ``tensors`` and ``config_yaml`` as checkpoint folder ``dst`` (replaced once the
    new one is complete), with the training state of checkpoint ``loaded`` (without its RNG,
    at its step) plus ``state_updates``; verified by loading the result. Files of an existing
    ``dst`` that a checkpoint does not hold (its ``eval_results.md``) are carried over."""
    from vla_gr.policy.factory import load_policy

    dst = Path(dst)
    staging = dst.parent / f".export-{dst.name}-{os.getpid()}"
    if staging.exists():
        shutil.rmtree(staging)
    state = {k: v for k, v in loaded.state.items() if k != "rng"}
    state.update(state_updates)
    written = save_checkpoint(
        staging, int(loaded.state.get("step", 0)), tensors, state, config_yaml, links=()
    )
    if dst.exists():
        for kept in sorted(dst.iterdir()):
            if kept.is_file() and not (written / kept.name).exists():
                shutil.copy2(kept, written / kept.name)
        shutil.rmtree(dst)
    os.replace(written, dst)
    shutil.rmtree(staging)
    load_policy(dst)  # the result verifies and loads
    return dst
