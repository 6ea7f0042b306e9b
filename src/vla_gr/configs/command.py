"""Command-line plumbing shared by every app: arguments, logging, one-line user errors.

Each app (``vla_gr.train``, ``vla_gr.demo``, ``vla_gr.data.collect``, ...) exposes
``run_from_cli(config_name, overrides)``; ``vla-gr <command>`` and ``python -m
vla_gr.<module>`` both run it through :func:`run_command`, which turns the errors a user
causes (``UserError``: bad recipe, key, value, store; a missing or existing file) into
``<prog>: error: <message>`` (at most two lines) on stderr and exit code 2.
``--verbose`` or ``HYDRA_FULL_ERROR=1`` lets the full traceback through instead.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Sequence

from vla_gr.errors import UserError

#: Exceptions whose message is all a user needs (no traceback on the command line).
USER_ERRORS: tuple[type[BaseException], ...] = (
    UserError,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)
EXIT_USAGE = 2


def add_verbose_argument(parser: argparse.ArgumentParser) -> None:
    """``--verbose``: show the traceback of an error instead of its one-line message."""
    parser.add_argument(
        "--verbose",
        "-v",
        action="store_true",
        help="on an error, show the full traceback (also: HYDRA_FULL_ERROR=1)",
    )


def add_hydra_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config-name``, free ``key=value`` overrides and ``--verbose``."""
    from vla_gr.configs import DEFAULT_CONFIG

    parser.add_argument("--config-name", "-cn", default=DEFAULT_CONFIG, help="recipe name")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. env.image_size=128")
    add_verbose_argument(parser)


def configure_logging() -> None:
    """INFO logging to stderr with timestamps (a no-op when logging is already set up);
    PyOpenGL's start-up notes stay quiet."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    logging.getLogger("OpenGL").setLevel(logging.WARNING)


def shows_tracebacks(verbose: bool) -> bool:
    """True when ``--verbose`` was given or ``HYDRA_FULL_ERROR=1`` is set."""
    return verbose or os.environ.get("HYDRA_FULL_ERROR") == "1"


def error_message(err: BaseException) -> str:
    """The message of a user error in at most two lines."""
    if isinstance(err, OSError) and err.filename is not None and err.strerror:
        text = f"{err.strerror}: {err.filename}"
    else:
        text = str(err) or type(err).__name__
    return "\n".join(text.splitlines()[:2])


def run_command(prog: str, func: Callable[..., object], *args, verbose: bool = False) -> int:
    """``func(*args)`` as a command: its int result (0 otherwise) is the exit code; a user
    error prints ``<prog>: error: ...`` on stderr and gives 2 (re-raised when verbose)."""
    try:
        result = func(*args)
    except USER_ERRORS as err:
        if shows_tracebacks(verbose):
            raise
        sys.stderr.write(f"{prog}: error: {error_message(err)}\n")
        return EXIT_USAGE
    return int(result) if isinstance(result, int) else 0


def module_main(
    module: str,
    run_from_cli: Callable[[str, Sequence[str]], object],
    argv: Sequence[str] | None = None,
) -> int:
    """Entry for ``python -m vla_gr.<module>``: parse argv, run ``run_from_cli``."""
    parser = argparse.ArgumentParser(prog=f"python -m vla_gr.{module}")
    add_hydra_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging()
    return run_command(
        parser.prog, run_from_cli, args.config_name, args.overrides, verbose=args.verbose
    )
