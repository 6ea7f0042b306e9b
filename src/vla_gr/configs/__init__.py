"""Hydra recipes shipped inside the package, and the loader every command uses."""

from __future__ import annotations

from collections.abc import Sequence

from hydra import compose, initialize_config_module
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from vla_gr.configs.schema import VLAGRConfig, register_configs

DEFAULT_CONFIG = "config_cpu"


def load_config(
    config_name: str = DEFAULT_CONFIG, overrides: Sequence[str] = ()
) -> tuple[DictConfig, VLAGRConfig]:
    """Compose ``config_name`` with Hydra ``overrides`` and validate it.

    Returns the resolved DictConfig (for saving) and the validated dataclass tree (for use).
    Unknown keys raise Hydra's ``ConfigCompositionException``; invalid values raise
    ``ValueError`` naming the key.
    """
    register_configs()
    GlobalHydra.instance().clear()
    with initialize_config_module(config_module="vla_gr.configs", version_base="1.3"):
        cfg = compose(config_name=config_name, overrides=list(overrides))
    OmegaConf.resolve(cfg)
    return cfg, OmegaConf.to_object(cfg)


__all__ = ["load_config", "VLAGRConfig", "DEFAULT_CONFIG"]
