"""How well the instruction lexicon reads instructions in words it was never given.

    python benchmarks/bench_instruction_lexicon.py [--count 2000] [--out PATH]

Instructions come from :func:`vla_gr.training.instruction_reader.reader_corpus` (random goal
descriptions with exact labels) in each wording: the templates, the *validation*
paraphrase vocabulary (the settings grid, where ``word_senses``, ``room_threshold`` and
``category_margin`` are chosen) and the *held-out* ones (the chosen settings only, alone, with
``locative_senses``, with ``locative_senses`` and ``place_senses``, with
``clause_places`` too when validation chooses it, and with ``noun_heads`` too when it changes
no template reading and lowers no validation score: what is reported; the template readings are
checked to be the same with all of them, the validation readings with the first three). Per
field (goal category, relation anchor, room type): the share of instructions where the lexicon
names the right class, where it names a wrong one, and where every field is right. Writes
``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

from vla_gr.agent.perception import InstructionLexicon, InstructionLexiconConfig
from vla_gr.envs.paraphrase import VOCABULARIES
from vla_gr.machine import describe_machine
from vla_gr.training.instruction_reader import reader_corpus

logger = logging.getLogger("bench_instruction_lexicon")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_instruction_lexicon"
FIELDS = ("category", "anchor", "room")
GRID = [(w, t, m) for w in (False, True) for t in (0.55, 0.6, 0.65, 0.7) for m in (0.0, 0.05, 0.1)]


def reading_scores(lexicon: InstructionLexicon, corpus: dict) -> dict:
    """Per field of ``corpus`` (labels: 0 = not named, else 1 + index into the lexicon's
    categories or room types): ``right`` / ``wrong`` = shares of instructions where the
    lexicon names the right / a wrong class; ``all_right`` = share with every field right
    (an unnamed field is right when the lexicon names nothing)."""
    c = lexicon.config
    n = len(corpus["instructions"])
    right = {f: 0 for f in FIELDS}
    wrong = {f: 0 for f in FIELDS}
    all_right = 0
    for j, text in enumerate(corpus["instructions"]):
        reading = lexicon.read(text)
        named = {
            "category": reading.category,
            "anchor": reading.anchor,
            "room": reading.room,
        }
        ok = True
        for f in FIELDS:
            names = c.room_types if f == "room" else c.categories
            got = 0 if named[f] is None else list(names).index(named[f]) + 1
            label = int(corpus[f][j])
            if got:
                right[f] += got == label
                wrong[f] += got != label
            ok &= got == label
        all_right += ok
    out: dict = {"instructions": n, "all_right": round(all_right / n, 4)}
    for f in FIELDS:
        out[f] = {
            "named": round(float(np.mean(corpus[f] > 0)), 4),
            "right": round(right[f] / n, 4),
            "wrong": round(wrong[f] / n, 4),
        }
    return out


def net_right(scores: dict) -> float:
    """Right readings minus wrong ones, summed over the fields: a wrong reading sends S2
    after another object (or rejects the right one), an empty one leaves it as it was."""
    return sum(scores[f]["right"] - scores[f]["wrong"] for f in FIELDS)


def _row(vocabulary: str, senses: bool, threshold: float, margin: float, scores: dict) -> str:
    cells = [f"{scores[f]['right']:.3f} / {scores[f]['wrong']:.3f}" for f in FIELDS]
    return (
        f"| {vocabulary} | {'on' if senses else 'off'} | {threshold} | {margin} | "
        + " | ".join(cells)
        + (f" | {scores['all_right']:.3f} |")
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=2000, help="instructions per vocabulary")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", default=str(DEFAULT_OUT))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    corpora = {v: reader_corpus(args.count, args.seed, v) for v in ("template", "validation")}
    rows = []
    for senses, threshold, margin in GRID:
        config = InstructionLexiconConfig(
            word_senses=senses, room_threshold=threshold, category_margin=margin
        )
        scores = reading_scores(InstructionLexicon(config), corpora["validation"])
        rows.append(
            {"word_senses": senses, "room_threshold": threshold, "category_margin": margin} | scores
        )
    default = InstructionLexiconConfig()
    chosen = max(  # ties go to the config's defaults
        rows,
        key=lambda r: (
            round(net_right(r), 6),
            r["room_threshold"] == default.room_threshold,
            r["category_margin"] == default.category_margin,
        ),
    )
    settings = {k: chosen[k] for k in ("word_senses", "room_threshold", "category_margin")}
    config = InstructionLexiconConfig(**settings)
    lexicon = InstructionLexicon(config)
    variants = {
        "": lexicon,
        ", locative_senses": InstructionLexicon(
            InstructionLexiconConfig(**settings, locative_senses=True)
        ),
        ", locative_senses, place_senses": InstructionLexicon(
            InstructionLexiconConfig(**settings, locative_senses=True, place_senses=True)
        ),
    }
    checked = {  # what clean runs and the selection read, by each variant
        name: [reading_scores(v, corpora[name]) for v in variants.values()]
        for name in ("template", "validation")
    }
    for name, scores in checked.items():
        if len({score["all_right"] for score in scores}) != 1:
            raise AssertionError(f"the {name} readings differ between {list(variants)}")
    # clause_places changes validation readings: chosen there, by the same score as the grid
    clause = InstructionLexicon(
        InstructionLexiconConfig(
            **settings, locative_senses=True, place_senses=True, clause_places=True
        )
    )
    clause_scores = {n: reading_scores(clause, corpora[n]) for n in ("template", "validation")}
    if clause_scores["template"] != checked["template"][0]:
        raise AssertionError("clause_places changes template readings")
    clause_chosen = net_right(clause_scores["validation"]) > net_right(checked["validation"][-1])
    if clause_chosen:
        variants[", locative_senses, place_senses, clause_places"] = clause
    # noun_heads reads nouns after modifiers ("the great room"), which neither the templates
    # nor the validation words have: kept when it changes none of their readings
    heads = InstructionLexicon(dataclasses.replace(clause.config, noun_heads=True))
    heads_scores = {n: reading_scores(heads, corpora[n]) for n in ("template", "validation")}
    heads_kept = heads_scores["template"] == clause_scores["template"] and net_right(
        heads_scores["validation"]
    ) >= net_right(clause_scores["validation"])
    if clause_chosen and heads_kept:
        variants[", locative_senses, place_senses, clause_places, noun_heads"] = heads
    held_out = {}
    for vocabulary in (v for v in VOCABULARIES if v.endswith("held_out")):
        corpus = reader_corpus(args.count, args.seed, vocabulary)
        for suffix, variant in variants.items():
            held_out[f"{vocabulary}{suffix}"] = reading_scores(variant, corpus)
    result = {
        "count": args.count,
        "seed": args.seed,
        "validation_grid": rows,
        "chosen": settings,
        "validation_place_senses": checked["validation"][-1],
        "validation_clause_places": clause_scores["validation"],
        "clause_places_chosen": clause_chosen,
        "validation_noun_heads": heads_scores["validation"],
        "noun_heads_kept": heads_kept,
        "template": checked["template"][0],  # the chosen settings alone
        **held_out,
        "machine": describe_machine(),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    head = [
        "| vocabulary | word_senses | room_threshold | category_margin | category right / wrong "
        "| anchor right / wrong | room right / wrong | all fields right |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines = [
        f"# Instruction lexicon: {args.count} instructions per vocabulary (seed {args.seed})",
        "",
        "Shares of all instructions. Chosen on `validation`: the most right readings minus "
        "wrong ones over the three fields (a wrong reading sends S2 after another object or "
        "rejects the right one; an empty one leaves S2 as it was), ties to the defaults. "
        "The held-out vocabularies are read with the chosen settings only, alone, with "
        "`locative_senses` and with `place_senses` too (neither changes the share of "
        "`validation` or `template` readings that are right).",
        "",
        *head,
        *(_row("validation", *(r[k] for k in settings), r) for r in rows),
        "",
        "With the chosen settings, `locative_senses` and `place_senses`, `clause_places` "
        f"{'is' if clause_chosen else 'is not'} chosen on `validation` (right minus wrong "
        f"{net_right(checked['validation'][-1]):.3f} without, "
        f"{net_right(clause_scores['validation']):.3f} with; it changes no template reading):",
        "",
        *head,
        _row("validation, place_senses", *settings.values(), checked["validation"][-1]),
        _row("validation, clause_places", *settings.values(), clause_scores["validation"]),
        "",
        "`noun_heads` (a word before a noun that says which or what kind is passed over: "
        '"the great room") reads phrases that neither the templates nor the validation '
        "words have; it is kept when it changes no template reading and lowers no validation "
        f"score: {'kept' if heads_kept else 'not kept'} (right minus wrong "
        f"{net_right(heads_scores['validation']):.3f}).",
        "",
        *head,
        _row("template", *settings.values(), result["template"]),
        *(_row(name, *settings.values(), scores) for name, scores in held_out.items()),
        "",
        f"Named shares: category {result['held_out']['category']['named']}, anchor "
        f"{result['held_out']['anchor']['named']}, room {result['held_out']['room']['named']}.",
        "",
        f"Machine: {result['machine']['cpu']}, {result['machine']['cores']} cores, "
        f"torch {result['machine']['torch']}.",
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
