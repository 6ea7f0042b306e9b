"""The instruction reader's start-up: building its word table from WordNet, once per process
(every eval worker, every `vla-gr read`), with ASCII text folded the short way and every
string through each folding step, side by side in one run.

    python benchmarks/bench_reader_startup.py [--repeats 5] \
        [--out benchmarks/results/bench_reader_startup]

WordNet is loaded once, untimed; each repeat builds the table both ways (the order alternating)
and checks that both tables are equal. Quoted: medians over the repeats and their ratio.
Writes ``<out>.json`` and ``<out>.md``. Run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from pathlib import Path
from unittest import mock

import numpy as np

from vla_gr.machine import describe_machine

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_reader_startup"


def build(every_step: bool):
    """(seconds, table) of one word table (its nouns too, as the first reading builds them)
    with ASCII folded the short way or through every step."""
    from vla_gr.agent.reading import text
    from vla_gr.agent.reading.vocabulary import WordTable
    from vla_gr.text_fold import _fold_unicode

    patch = mock.patch.object(text, "fold_to_ascii", _fold_unicode)
    t0 = time.perf_counter()
    with patch if every_step else contextlib.nullcontext():
        table = WordTable()
        _ = table._nouns
    return time.perf_counter() - t0, table


def median_table(times: dict[str, list[float]], head: str) -> tuple[dict[str, float], list[str]]:
    """The median seconds of each way's runs, and the rows of a markdown table of them (its
    first column headed ``head``)."""
    med = {name: float(np.median(v)) for name, v in times.items()}
    rows = [f"| {head} | median s | runs |", "|---|---|---|"]
    rows += [
        f"| {n} | {med[n]:.2f} | {' / '.join(f'{x:.2f}' for x in v)} |" for n, v in times.items()
    ]
    return med, rows


def write_results(out: Path, lines: list[str], payload: dict) -> None:
    """Print ``lines`` and write them to ``<out>.md``, ``payload`` to ``<out>.json``."""
    text = "\n".join(lines) + "\n"
    print(text)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text(text, encoding="utf-8")
    out.with_suffix(".json").write_text(json.dumps(payload, indent=2), encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args()
    from vla_gr.agent.reading.vocabulary import _wordnet

    t0 = time.perf_counter()
    _wordnet()
    load = time.perf_counter() - t0
    times = {"every step": [], "ASCII short way": []}
    for k in range(args.repeats):
        order = [True, False] if k % 2 == 0 else [False, True]
        tables = {}
        for every_step in order:
            total, table = build(every_step)
            name = "every step" if every_step else "ASCII short way"
            times[name].append(total)
            tables[name] = table
        a, b = tables.values()
        same = a.objects == b.objects and a.rooms == b.rooms and a.known == b.known
        if not (same and a.compounds == b.compounds and a._nouns == b._nouns):
            raise SystemExit("the two word tables differ")
    med, table = median_table(times, "folding")
    ratio = med["every step"] / med["ASCII short way"]
    machine = describe_machine(calibrate=False)
    lines = [
        "# The reader's word table at start-up, folding ASCII the short way or every step",
        "",
        f"`python benchmarks/bench_reader_startup.py --repeats {args.repeats}`",
        "",
        f"Machine: {machine['cpu']}, {machine['cores']} cores. WordNet loaded once first: "
        f"{load:.2f} s (not in the table). Both ways build equal tables.",
        "",
        *table,
        "",
        f"Ratio (every step / short way): **{ratio:.2f}x**.",
    ]
    payload = {"machine": machine, "wordnet_load_s": load, "seconds": times, "median_s": med,
               "ratio": ratio}  # fmt: skip
    write_results(args.out, lines, payload)


if __name__ == "__main__":
    main()
