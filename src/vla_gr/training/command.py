"""The shared ending of the training stages' ``main()``: parse, log, run, report errors."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Sequence

from vla_gr.errors import UserError


def run_command(
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    work: Callable[[argparse.Namespace], object],
    limit_threads: bool = True,
) -> int:
    """Parse ``argv`` with ``parser`` and run ``work(args)``; return the exit status.

    Logs at INFO with timestamps and, when ``limit_threads``, lets torch use at most two
    threads (torch is imported only then). A :class:`~vla_gr.errors.UserError` from ``work``
    becomes one line ``PROG: error: MESSAGE`` on stderr and status 2; other exceptions
    propagate. ``work``'s return value is ignored: success is 0.
    """
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    if limit_threads:
        import torch

        torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
    try:
        work(args)
    except UserError as err:
        sys.stderr.write(f"{parser.prog}: error: {err}\n")
        return 2
    return 0
