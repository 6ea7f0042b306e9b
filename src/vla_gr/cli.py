"""``vla-gr``: one entry point, one subcommand per app.

Every subcommand takes ``--config-name NAME`` and Hydra ``key=value`` overrides, and is
also runnable as ``python -m vla_gr.<module>``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Callable, Sequence

from vla_gr import __version__

# subcommand -> ("module:function", one-line help). Functions take (config_name, overrides).
COMMANDS: dict[str, tuple[str, str]] = {
    "collect": ("vla_gr.data.collect:run_from_cli", "run the expert and write a zarr dataset"),
    "demo": ("vla_gr.demo:run_from_cli", "run episodes, print metrics, write GIF + top-down PNG"),
    "eval": ("vla_gr.evaluate:run_from_cli", "closed-loop evaluation of an agent: metrics, report"),
    "train": ("vla_gr.train:run_from_cli", "train the agent (single process or under torchrun)"),
}


def _resolve(target: str) -> Callable[[str, Sequence[str]], object]:
    module_name, func_name = target.split(":")
    return getattr(importlib.import_module(module_name), func_name)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vla-gr",
        description="VLA-GR: language-conditioned robot navigation policies.",
    )
    parser.add_argument("--version", action="version", version=f"vla-gr {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (_, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        add_hydra_arguments(p)
    return parser


def add_hydra_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config-name`` and free ``key=value`` overrides, as every subcommand takes."""
    from vla_gr.configs import DEFAULT_CONFIG

    parser.add_argument("--config-name", "-cn", default=DEFAULT_CONFIG, help="recipe name")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. env.image_size=128")


def module_main(command: str, argv: Sequence[str] | None = None) -> int:
    """Entry for ``python -m vla_gr.<module>``: parse argv for one subcommand and run it."""
    parser = argparse.ArgumentParser(prog=f"python -m vla_gr.{command}")
    add_hydra_arguments(parser)
    args = parser.parse_args(argv)
    return _run(command, args.config_name, args.overrides)


def _run(command: str, config_name: str, overrides: Sequence[str]) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    result = _resolve(COMMANDS[command][0])(config_name, overrides)
    return int(result) if isinstance(result, int) else 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return _run(args.command, args.config_name, args.overrides)


if __name__ == "__main__":
    sys.exit(main())
