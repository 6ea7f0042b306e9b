"""Hydra recipes shipped inside the package, and the loader every command uses."""

from __future__ import annotations

from collections.abc import Sequence

from hydra import compose, initialize_config_module
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from vla_gr.configs.explain import explain
from vla_gr.configs.schema import VLAGRConfig, register_configs
from vla_gr.errors import ConfigError

DEFAULT_CONFIG = "config_cpu"


def load_config(
    config_name: str = DEFAULT_CONFIG, overrides: Sequence[str] = ()
) -> tuple[DictConfig, VLAGRConfig]:
    """Compose ``config_name`` with Hydra ``overrides`` and validate it.

    Returns the resolved DictConfig (for saving) and the validated dataclass tree (for use).
    An unknown recipe or key, a value of the wrong type or an invalid value raises
    ``ConfigError`` (a ``ValueError``) naming the key and the valid choices; the original
    error is its ``__cause__``.
    """
    register_configs()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(config_module="vla_gr.configs", version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=list(overrides))
        OmegaConf.resolve(cfg)
        return cfg, OmegaConf.to_object(cfg)
    except ConfigError:
        raise
    except (HydraException, OmegaConfBaseException) as err:
        raise explain(err, config_name, overrides) from err
    except ValueError as err:  # a dataclass's validation: the message names the key
        raise ConfigError(str(err)) from err


__all__ = ["load_config", "ConfigError", "VLAGRConfig", "DEFAULT_CONFIG"]
