"""The instruction reader on hand-written requests: reading accuracy (every field right), per
field, how many it understood, calibration (ECE of the field confidences), how many of the
requests it must not act on it refused, and its cost per request.

    python benchmarks/bench_reader.py --checkpoint checkpoints/vla_gr_cpu \
        [--sets benchmarks/language/*.jsonl] [--out benchmarks/results/bench_reader]

Each set is a JSONL file of ``benchmarks/language/`` (requests with the fields they name, or
with the ``kind`` of request the agent must not act on). Cost: the first reading of each
request (normaliser, word tables, encoder, tagger; one torch thread) and a cached reading,
medians over ``--repeats`` passes. Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from vla_gr.machine import describe_machine
from vla_gr.policy import load_policy
from vla_gr.training.reader_training import load_request_rows, reading_scores

ROOT = Path(__file__).resolve().parent
LANGUAGE = ROOT / "language"


def measure(policy, path: Path, repeats: int) -> dict:
    """Scores of one set and the reader's time per request (first and cached readings)."""
    rows = load_request_rows([path])
    reader = policy.instruction_reader
    first, cached = [], []
    readings = None
    for _ in range(repeats):
        reader._cache.clear()
        times, again = [], []
        out = []
        for row in rows:
            t0 = time.perf_counter()
            out.append(reader.read(row["request"]))
            times.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            reader.read(row["request"])
            again.append(time.perf_counter() - t0)
        readings = readings or out
        first.append(np.median(times) * 1e3)
        cached.append(np.median(again) * 1e3)
    scores = reading_scores(readings, rows)
    scores["first_read_ms_p50"] = round(float(np.median(first)), 3)
    scores["cached_read_ms_p50"] = round(float(np.median(cached)), 4)
    scores["misread"] = [
        {"request": row["request"], "reading": r.as_dict()}
        for r, row in zip(readings, rows)
        if (row["refuse"] and r.understood)
        or (not row["refuse"] and not (r.understood and _right(r, row)))
    ]
    return scores


def _right(reading, row) -> bool:
    f = row["fields"]
    return reading.fields() == {"category": f["category"], "color": f["color"],
                                "room": f["room"], "anchor": f["near"]}  # fmt: skip


def table(results: dict) -> str:
    lines = [
        "| set | requests | reading accuracy | category / colour / room / anchor | understood "
        "| acted on wrongly | ECE | refused (must not act) | first read p50 ms |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in results.items():
        f = s.get("field_accuracy")
        fields = (
            " / ".join(f"{f[k]:.3f}" for k in ("category", "color", "room", "anchor")) if f else "-"
        )
        refused = f"{s['refused']:.3f} of {s['refusals']}" if "refusals" in s else "-"
        lines.append(
            f"| {name} | {s.get('requests', 0)} | "
            f"{s['reading_accuracy']:.3f} | {fields} | {s['understood']:.3f} | "
            f"{s['acted_on_wrongly']} | {s['ece']:.4f} | {refused} | {s['first_read_ms_p50']} |"
            if "requests" in s
            else f"| {name} | 0 | - | - | - | - | - | {refused} | {s['first_read_ms_p50']} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument(
        "--sets", nargs="+", default=sorted(str(p) for p in LANGUAGE.glob("*.jsonl"))
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "results" / "bench_reader"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(1)
    policy = load_policy(args.checkpoint)
    if policy.instruction_reader is None:
        raise SystemExit(f"{args.checkpoint} has no instruction reader")
    results = {Path(p).stem: measure(policy, Path(p), args.repeats) for p in args.sets}
    c = policy.instruction_reader.config
    head = (
        f"# The instruction reader on hand-written requests\n\n"
        f"`python benchmarks/bench_reader.py --checkpoint {args.checkpoint}` on "
        f"{describe_machine()}; temperature {c.temperature}, min_confidence "
        f"{c.min_confidence}. Sets in `benchmarks/language/` (README there says which are "
        f"blind).\n\n"
    )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(results, indent=1) + "\n")
    out.with_suffix(".md").write_text(head + table(results) + "\n")
    print(head + table(results))


if __name__ == "__main__":
    main()
