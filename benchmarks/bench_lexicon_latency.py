"""What the instruction lexicon costs: the first reading of a paraphrase, once per episode.

    python benchmarks/bench_lexicon_latency.py [--count 200] [--repeats 5]

``count`` instructions in the held-out paraphrase vocabulary, each read by a lexicon with
empty caches (the first step of an episode, where the reading happens), one thread, with and
without ``word_senses``, side by side in one run; ``repeats`` passes, the median per
instruction. Also the time to build each lexicon (MiniLM's name embeddings, WordNet's load).
Writes ``benchmarks/results/bench_lexicon_latency.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from vla_gr.agent.perception import InstructionLexicon, InstructionLexiconConfig
from vla_gr.machine import describe_machine
from vla_gr.training.instruction_reader import reader_corpus

OUT = Path(__file__).resolve().parent / "results" / "bench_lexicon_latency"


def first_readings(lexicon: InstructionLexicon, texts: list[str], repeats: int) -> np.ndarray:
    """Median over ``repeats`` of each text's first ``canonical`` call (ms), (N,)."""
    times = np.zeros((repeats, len(texts)))
    for r in range(repeats):
        for j, text in enumerate(texts):
            lexicon._canonical.clear()  # an episode's first reading: nothing cached ...
            lexicon._words.clear()  # ... not even the words' embeddings
            if lexicon._senses is not None:
                lexicon._senses._cache.clear()
            t0 = time.perf_counter()
            lexicon.canonical(text)
            times[r, j] = (time.perf_counter() - t0) * 1e3
    return np.median(times, axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(1)
    texts = list(reader_corpus(args.count, args.seed, "held_out")["instructions"])
    rows = {}
    for senses in (False, True):
        t0 = time.perf_counter()
        lexicon = InstructionLexicon(InstructionLexiconConfig(enabled=True, word_senses=senses))
        build = time.perf_counter() - t0
        ms = first_readings(lexicon, texts, args.repeats)
        rows["word senses" if senses else "encoder only"] = {
            "build_s": round(build, 2),
            "p50_ms": round(float(np.percentile(ms, 50)), 2),
            "p95_ms": round(float(np.percentile(ms, 95)), 2),
            "max_ms": round(float(ms.max()), 2),
        }
    result = {"count": args.count, "repeats": args.repeats, "rows": rows}
    result["machine"] = describe_machine()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    m = result["machine"]
    lines = [
        f"# Instruction lexicon: first reading of {args.count} held-out paraphrases",
        "",
        f"`python benchmarks/bench_lexicon_latency.py --count {args.count} --repeats "
        f"{args.repeats}`: one thread, caches emptied before each reading, median of "
        f"{args.repeats} passes per instruction. Build: constructing the lexicon, once per "
        "process (the first row's includes loading MiniLM, the second's WordNet).",
        "",
        "| lexicon | build s | first reading p50 ms | p95 ms | max ms |",
        "|---|---|---|---|---|",
        *(
            f"| {name} | {r['build_s']} | {r['p50_ms']} | {r['p95_ms']} | {r['max_ms']} |"
            for name, r in rows.items()
        ),
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, torch {m['torch']}.",
    ]
    OUT.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
