"""Errors a user causes and can fix (a bad key, value, file or path).

Their messages say what is wrong, where (the key, the file) and what would be valid; the
command line prints them on one or two lines, without a traceback, and exits with code 2.
This module imports nothing, so every layer may raise them.
"""

from __future__ import annotations


class UserError(Exception):
    """An error caused by the user's input; its message is complete on its own."""


class ConfigError(UserError, ValueError):
    """A recipe name, override or config value that is not valid; names the key."""
