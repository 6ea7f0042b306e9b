"""Command-line plumbing shared by every app: arguments, logging, one-line user errors.

Each app (``vla_gr.train``, ``vla_gr.demo``, ``vla_gr.data.collect``, ...) exposes
``run_from_cli(config_name, overrides)``; ``vla-gr <command>`` and ``python -m
vla_gr.<module>`` both run it through :func:`run_command`, which turns the errors a user
causes (``UserError``: bad recipe, key, value, store; a missing or existing file) into
``<prog>: error: <message>`` (at most two lines) on stderr and exit code 2.
``--verbose`` or ``HYDRA_FULL_ERROR=1`` lets the full traceback through instead.

``--help`` lists the config keys the command reads, with their defaults and meanings
(:mod:`vla_gr.configs.keys`); ``--cfg job`` prints the resolved config the command would run
with (``--package KEY``: one section) and runs nothing.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Sequence

from vla_gr.errors import ConfigError, UserError

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
#: What ``--cfg`` prints: ``job``, the config the command runs with (Hydra's name for it).
CFG_CHOICES = ("job",)
#: ``python -m vla_gr.<module>`` -> the command it is (``vla-gr <command>``).
COMMAND_OF_MODULE = {"evaluate": "eval", "data.collect": "collect"}
#: ``compose(config_name, overrides) -> (resolved DictConfig, VLAGRConfig)``.
Compose = Callable[[str, Sequence[str]], tuple]


def add_verbose_argument(parser: argparse.ArgumentParser) -> None:
    """``--verbose``: show the traceback of an error instead of its one-line message."""
    parser.add_argument(
        "--verbose",
        "-v",
        action="store_true",
        help="on an error, show the full traceback (also: HYDRA_FULL_ERROR=1)",
    )


class KeysHelpAction(argparse.Action):
    """``-h/--help``: the usage, then the keys ``command`` reads with their defaults in the
    recipe named by an earlier ``--config-name`` (else the default recipe) and meanings."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, command: str = "", help=None):
        super().__init__(option_strings, dest, default=argparse.SUPPRESS, nargs=0, help=help)
        self.command = command

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from vla_gr.configs import DEFAULT_CONFIG
        from vla_gr.configs.keys import keys_help

        parser.print_help()
        config_name = getattr(namespace, "config_name", None) or DEFAULT_CONFIG
        sys.stdout.write("\n" + keys_help(self.command, config_name) + "\n")
        parser.exit()


def add_hydra_arguments(parser: argparse.ArgumentParser, command: str | None = None) -> None:
    """``--config-name``, free ``key=value`` overrides, ``--cfg job``, ``--package`` and
    ``--verbose``; given ``command`` (a parser made with ``add_help=False``), ``-h/--help``
    that also lists the keys ``command`` reads."""
    from vla_gr.configs import DEFAULT_CONFIG

    if command is not None:
        parser.add_argument(
            "-h",
            "--help",
            action=KeysHelpAction,
            command=command,
            help="show this help and the command's keys (defaults, meanings), then exit",
        )
    parser.add_argument("--config-name", "-cn", default=DEFAULT_CONFIG, help="recipe name")
    parser.add_argument(
        "--cfg",
        "-c",
        choices=CFG_CHOICES,
        help="print the resolved config the command would run with, and run nothing",
    )
    parser.add_argument(
        "--package",
        "-p",
        metavar="KEY",
        help="with --cfg job: print only this key or section, e.g. eval or model.gr_field",
    )
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. env.image_size=128")
    add_verbose_argument(parser)


def print_config(
    config_name: str,
    overrides: Sequence[str],
    compose: Compose | None = None,
    package: str | None = None,
) -> int:
    """``--cfg job``: the resolved config that ``compose`` (default: ``load_config``) makes
    of ``config_name`` and ``overrides``, as YAML on stdout; only key ``package`` if given.
    A key that does not compose, or a ``package`` that is not a key, is a ``ConfigError``."""
    from omegaconf import OmegaConf

    from vla_gr.configs import load_config

    resolved, _ = (compose or load_config)(config_name, overrides)
    node = resolved
    if package:
        node = OmegaConf.select(resolved, package, default=KeyError)
        if node is KeyError:
            raise ConfigError(f"--package {package}: no such key; sections: {', '.join(resolved)}")
        if not OmegaConf.is_config(node):
            node = OmegaConf.create({package: node})
    sys.stdout.write(OmegaConf.to_yaml(node, resolve=True))
    sys.stdout.flush()
    return 0


def run_hydra_command(
    prog: str,
    args: argparse.Namespace,
    run_from_cli: Callable[[str, Sequence[str]], object],
    compose: Compose | None = None,
) -> int:
    """Run an app for parsed ``add_hydra_arguments`` ``args``: ``--cfg job`` prints the
    config ``compose`` makes, else ``run_from_cli(config_name, overrides)`` runs."""
    if args.cfg:
        return run_command(
            prog,
            print_config,
            args.config_name,
            args.overrides,
            compose,
            args.package,
            verbose=args.verbose,
        )
    if args.package:
        sys.stderr.write(f"{prog}: error: --package {args.package} works with --cfg job\n")
        return EXIT_USAGE
    return run_command(prog, run_from_cli, args.config_name, args.overrides, verbose=args.verbose)


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
    compose: Compose | None = None,
) -> int:
    """Entry for ``python -m vla_gr.<module>``: parse argv, run ``run_from_cli`` (or print
    the config ``compose`` makes, for ``--cfg job``)."""
    parser = argparse.ArgumentParser(prog=f"python -m vla_gr.{module}", add_help=False)
    add_hydra_arguments(parser, COMMAND_OF_MODULE.get(module, module))
    args = parser.parse_args(argv)
    configure_logging()
    return run_hydra_command(parser.prog, args, run_from_cli, compose)
