"""``vla-gr read TEXT [checkpoint=PATH]``: how an agent reads a request, without a house.

Loads the checkpoint's agent (default ``checkpoints/vla_gr_cpu``), reads ``TEXT`` with its
instruction reader (``policy.read``) and prints the reading as aligned lines::

    request     the red chair next to the tv
    understood  yes
    category    chair        0.98
    color       red          0.99
    room        -            0.97
    anchor      tv_monitor   0.95
    unknown     -
    reason      -

Exit code 0 when the request is understood, 3 when it is not (the agent would not act on it),
2 with one line on bad input (an unknown argument, a checkpoint that does not load, an agent
that reads no requests, a request the reader refuses). Also ``python -m vla_gr.read_cli``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from vla_gr.configs.command import add_verbose_argument, configure_logging, run_command
from vla_gr.errors import UserError

__all__ = [
    "DEFAULT_CHECKPOINT",
    "EXIT_NOT_UNDERSTOOD",
    "add_read_arguments",
    "format_reading",
    "load_reader",
    "run_from_cli",
]

DEFAULT_CHECKPOINT = "checkpoints/vla_gr_cpu"
EXIT_NOT_UNDERSTOOD = 3
#: The keys ``key=value`` arguments may set.
KEYS = ("checkpoint",)
_FIELDS = ("category", "color", "room", "anchor")


def add_read_arguments(parser: argparse.ArgumentParser) -> None:
    """``TEXT``, ``key=value`` settings (``checkpoint=PATH``) and ``--verbose``."""
    parser.add_argument("text", help="the request, e.g. 'find the red chair in the kitchen'")
    parser.add_argument(
        "settings", nargs="*", help=f"checkpoint=PATH (default {DEFAULT_CHECKPOINT})"
    )
    add_verbose_argument(parser)


def parse_settings(settings: Sequence[str]) -> dict[str, str]:
    """``["checkpoint=PATH"]`` -> ``{"checkpoint": PATH}`` with the defaults filled in;
    UserError in one line on anything else."""
    out = {"checkpoint": DEFAULT_CHECKPOINT}
    for item in settings:
        key, sep, value = item.partition("=")
        if not sep or key not in KEYS:
            raise UserError(
                f"unknown argument {item!r}; vla-gr read takes TEXT and "
                f"{', '.join(f'{k}=...' for k in KEYS)} (quote a request of several words)"
            )
        if not value:
            raise UserError(f"{key}= needs a value, e.g. {key}={DEFAULT_CHECKPOINT}")
        out[key] = value
    return out


def load_reader(path: str):
    """The agent of checkpoint ``path`` (``vla_gr.policy.load_policy``); UserError in one
    line when it does not load or reads no requests (has no ``read``)."""
    from vla_gr.checkpoint import CheckpointError
    from vla_gr.policy import load_policy

    try:
        policy = load_policy(path)
    except CheckpointError as err:
        raise UserError(str(err)) from err
    if getattr(policy, "read", None) is None:
        raise UserError(
            f"checkpoint {path} holds a {type(policy).__name__}, which reads no requests "
            "(only the dual-system agent has an instruction reader)"
        )
    return policy


def format_reading(text: str, reading) -> list[str]:
    """Aligned lines of ``reading`` (a ``Reading``) of request ``text``: the request,
    understood, each field with its confidence, how sure it is that the request asks to go
    somewhere (with the intent head), the unknown words, the reason."""
    from vla_gr.text_fold import fold_to_ascii

    fields = reading.as_dict()
    confidence = fields.get("confidence") or {}
    rows = [
        ("request", fold_to_ascii(text) or "(blank)", ""),
        ("understood", "yes" if reading.understood else "no", ""),
    ]
    for name in _FIELDS:
        sure = confidence.get(name)
        rows.append((name, _text(fields.get(name)), "-" if sure is None else f"{sure:.2f}"))
    if "request" in confidence:  # the intent head's probability that it asks to go anywhere
        rows.append(("asks", f"to go somewhere, confidence {confidence['request']:.2f}", ""))
    rows.append(("unknown", ", ".join(fields.get("unknown") or []) or "-", ""))
    rows.append(("reason", reading.reason or "-", ""))
    width = max(len(label) for label, _, _ in rows) + 2
    value_width = max(len(value) for label, value, _ in rows if label in _FIELDS) + 2
    lines = []
    for label, value, sure in rows:
        line = (
            f"{label:<{width}}{value:<{value_width}}{sure}" if sure else f"{label:<{width}}{value}"
        )
        lines.append(line.rstrip())
    return lines


def _text(value) -> str:
    return "-" if value is None else str(value)


def run_from_cli(text: str, settings: Sequence[str] = ()) -> int:
    """``vla-gr read TEXT [checkpoint=PATH]``: print the reading; 0 when understood, 3 when
    not (2 on bad input, through :func:`~vla_gr.configs.command.run_command`)."""
    from vla_gr.agent.reading import normalise_request

    normalise_request(text)  # a request the reader refuses: before the agent loads
    options = parse_settings(settings)
    policy = load_reader(options["checkpoint"])
    reading = policy.read(text)
    sys.stdout.write("\n".join(format_reading(text, reading)) + "\n")
    sys.stdout.flush()
    return 0 if reading.understood else EXIT_NOT_UNDERSTOOD


def main(argv: Sequence[str] | None = None) -> int:
    """Entry for ``python -m vla_gr.read_cli TEXT [checkpoint=PATH]``."""
    parser = argparse.ArgumentParser(
        prog="python -m vla_gr.read_cli", description=__doc__.split("\n")[0]
    )
    add_read_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging()
    return run_command(parser.prog, run_from_cli, args.text, args.settings, verbose=args.verbose)


if __name__ == "__main__":
    sys.exit(main())
