"""bench_instruction_lexicon: reading scores against hand counts."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from tests.agent.perception.test_lexicon import axis, lexicon

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_instruction_lexicon.py"
_spec = importlib.util.spec_from_file_location("bench_instruction_lexicon", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_reading_scores_count_right_wrong_and_whole_instructions():
    # couch -> sofa (right); telly -> bed (wrong: it means the tv); lounge -> living room
    lex = lexicon(
        {
            "couch": axis("sofa", 1.0, 0.1),
            "telly": axis("bed", 1.0, 0.1),
            "lounge": axis("living room", 1.0, 0.1),
        }
    )
    corpus = {
        "instructions": [
            "in the lounge find the couch",  # all right
            "find the telly near the couch",  # category wrong, anchor right
            "find the couch",  # all right
            "find the lamp in the kitchen",  # category: "lamp" is nothing known -> unnamed
        ],
        "category": np.array([2, 5, 2, 0]),  # 1-based: sofa, tv, sofa, none
        "anchor": np.array([0, 2, 0, 0]),
        "room": np.array([2, 0, 0, 1]),  # living room, -, -, kitchen
    }
    scores = bench.reading_scores(lex, corpus)
    assert scores["instructions"] == 4
    assert scores["category"] == {"named": 0.75, "right": 0.5, "wrong": 0.25}
    assert scores["anchor"] == {"named": 0.25, "right": 0.25, "wrong": 0.0}
    assert scores["room"] == {"named": 0.5, "right": 0.5, "wrong": 0.0}
    assert scores["all_right"] == 0.75  # the lamp: nothing named, as labelled


def test_net_right_weighs_a_wrong_reading_against_a_right_one():
    scores = {f: {"right": 0.5, "wrong": 0.1} for f in bench.FIELDS}
    assert abs(bench.net_right(scores) - 1.2) < 1e-12
    scores["category"]["wrong"] = 0.5  # as many wrong as right: the field adds nothing
    assert abs(bench.net_right(scores) - 0.8) < 1e-12
