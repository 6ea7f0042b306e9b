"""Value checks shared by every config and component: errors name the key and the choices.

Imports nothing from the package, so any layer (configs, core, envs, apps) may use it.
"""

from __future__ import annotations

__all__ = ["check_choice", "check_positive", "check_positive_int"]


def check_choice(key: str, value, choices) -> None:
    """Raise ValueError naming ``key`` when ``value`` is not one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{key}={value!r} is not valid; choose one of {list(choices)}")


def check_positive(key: str, value, allow_zero: bool = False) -> None:
    """Raise ValueError naming ``key`` when ``value`` is not > 0 (or >= 0)."""
    if not (value >= 0 if allow_zero else value > 0):
        raise ValueError(f"{key}={value!r} must be {'>= 0' if allow_zero else '> 0'}")


def check_positive_int(key: str, value) -> None:
    """Raise ValueError naming ``key`` unless ``value`` is an int > 0 (bools rejected)."""
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ValueError(f"{key}={value!r} must be a positive int")
