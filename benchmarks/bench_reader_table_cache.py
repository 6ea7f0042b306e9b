"""The reader's word table at a process's start: built from WordNet (WordNet loaded, its
lemmas walked: what every process paid before the cache) or read from the cache on disk
(:mod:`vla_gr.agent.reading.table_cache`), side by side, each in a fresh process.

    python benchmarks/bench_reader_table_cache.py [--repeats 5] \
        [--out benchmarks/results/bench_reader_table_cache]

Each repeat starts one process per way, the order alternating, with the cache in a temporary
folder written once before the first repeat. Each process times its own table (imports
excluded) and prints a digest of the table's state: both ways must give the same digest.
Quoted: medians over the repeats and their ratio. Writes ``<out>.json`` and ``<out>.md``. Run
it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_reader_startup import median_table, write_results

from vla_gr.machine import describe_machine

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_reader_table_cache"

# what a child process runs: one table, its seconds and a digest of its state
_CHILD = """
import hashlib, json, sys, time
from vla_gr.agent.reading.vocabulary import WordTable, word_table
t0 = time.perf_counter()
if sys.argv[1] == "built":
    table = WordTable()  # WordNet loaded and walked, nothing written
    _ = table._nouns
else:
    table = word_table()  # read from the cache
seconds = time.perf_counter() - t0
state = json.dumps(table.to_state(), sort_keys=True).encode()
print(json.dumps({"seconds": seconds, "digest": hashlib.sha256(state).hexdigest()}))
"""

WAYS = ("built", "cached")


def run(way: str, cache: str) -> dict:
    env = {**os.environ, "VLA_GR_CACHE": cache, "HF_HUB_OFFLINE": "1"}
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, way], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args()
    times: dict[str, list[float]] = {way: [] for way in WAYS}
    with tempfile.TemporaryDirectory() as cache:
        run("cached", cache)  # writes the cache (a miss builds it)
        for k in range(args.repeats):
            digests = set()
            for way in WAYS if k % 2 == 0 else WAYS[::-1]:
                result = run(way, cache)
                times[way].append(result["seconds"])
                digests.add(result["digest"])
            if len(digests) != 1:
                raise SystemExit("the built and the cached tables differ")
    med, table = median_table(times, "table")
    ratio = med["built"] / med["cached"]
    machine = describe_machine(calibrate=False)
    lines = [
        "# The reader's word table at a process's start: built from WordNet or read from disk",
        "",
        f"`python benchmarks/bench_reader_table_cache.py --repeats {args.repeats}`",
        "",
        f"Machine: {machine['cpu']}, {machine['cores']} cores. Each figure is one fresh "
        "process's own time for its table (imports excluded); both ways give the same table.",
        "",
        *table,
        "",
        f"Read from disk: **{ratio:.2f}x** faster than built from WordNet.",
    ]
    payload = {"machine": machine, "seconds": times, "median_s": med, "ratio": ratio}
    write_results(args.out, lines, payload)


if __name__ == "__main__":
    main()
