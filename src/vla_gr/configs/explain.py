"""Hydra / OmegaConf composition errors as one-or-two-line ``ConfigError`` messages."""

from __future__ import annotations

import dataclasses
import difflib
from importlib import resources

from hydra.errors import MissingConfigException, OverrideParseException
from omegaconf.errors import (
    ConfigAttributeError,
    ConfigKeyError,
    OmegaConfBaseException,
    ValidationError,
)

from vla_gr.errors import ConfigError


def recipe_names() -> list[str]:
    """Names of the recipes shipped in ``vla_gr.configs`` (``config_*.yaml``)."""
    files = resources.files("vla_gr.configs").iterdir()
    return sorted(f.name[: -len(".yaml")] for f in files if f.name.endswith(".yaml"))


def _omegaconf_cause(err: BaseException) -> OmegaConfBaseException | None:
    """The first OmegaConf error that names a key in ``err``'s chain of causes."""
    while err is not None:
        if isinstance(err, OmegaConfBaseException) and getattr(err, "full_key", None):
            return err
        err = err.__cause__ or err.__context__
    return None


def _fields(object_type) -> dict[str, str]:
    if object_type is None or not dataclasses.is_dataclass(object_type):
        return {}
    return {f.name: str(f.type) for f in dataclasses.fields(object_type)}


def explain(err: Exception, config_name: str, overrides) -> ConfigError:
    """A ``ConfigError`` naming the key / recipe and the valid choices for ``err``."""
    if isinstance(err, MissingConfigException):
        return ConfigError(f"unknown config name {config_name!r}; choose one of {recipe_names()}")
    if isinstance(err, OverrideParseException):
        lines = str(err).splitlines()  # "Error parsing override 'x'", the parser's reason
        detail = f" ({lines[1]})" if len(lines) > 1 else ""
        return ConfigError(f"{lines[0]}{detail}; overrides are key=value, e.g. training.steps=10")
    cause = _omegaconf_cause(err)
    if cause is None:
        return ConfigError(f"config {config_name!r}: {str(err).splitlines()[0]}")
    key, fields = cause.full_key, _fields(cause.object_type)
    parent = key.rpartition(".")[0] or "the config root"
    if isinstance(cause, (ConfigKeyError, ConfigAttributeError)):  # an unknown key
        close = difflib.get_close_matches(key.rpartition(".")[2], list(fields), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return ConfigError(
            f"unknown config key {key!r}{hint}\nvalid keys of {parent}: {', '.join(fields)}"
        )
    detail = str(cause.msg).splitlines()[0]
    if isinstance(cause, ValidationError):
        expected = fields.get(key.rpartition(".")[2])
        detail += f"; {key} must be {expected}" if expected else ""
    return ConfigError(f"{key}: {detail}")
