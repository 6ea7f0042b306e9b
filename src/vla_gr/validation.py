"""Validation helpers shared by every config dataclass: errors name the key and the choices."""

from __future__ import annotations


def check_choice(key: str, value, choices) -> None:
    """Raise ValueError naming ``key`` when ``value`` is not one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{key}={value!r} is not valid; choose one of {list(choices)}")


def check_positive(key: str, value, allow_zero: bool = False) -> None:
    """Raise ValueError naming ``key`` when ``value`` is not > 0 (or >= 0)."""
    if not (value >= 0 if allow_zero else value > 0):
        raise ValueError(f"{key}={value!r} must be {'>= 0' if allow_zero else '> 0'}")
