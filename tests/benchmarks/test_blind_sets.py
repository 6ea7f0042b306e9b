"""blind_sets: an episodes file of a request set carries the generator's fields."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from vla_gr.envs.episodes import load_episodes, sample_episode
from vla_gr.envs.instructions import parse_instruction

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "language" / "blind_sets.py"
_spec = importlib.util.spec_from_file_location("blind_sets", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def _row(index: int, request: str) -> dict:
    """A blind-set line on ``test`` episode ``index`` (a real one: files are checked against
    their houses), with the generator's fields and a hand-written ``request``."""
    spec = sample_episode("test", index)
    fields = parse_instruction(spec.instruction)
    return {"spec": spec.to_dict(), "fields": fields, "request": request}


ROWS = [
    _row(0, "that one over there, please"),
    _row(1, "the one by the door \u2014 thanks!"),
]


def test_a_request_episode_carries_the_generators_fields(tmp_path):
    specs = load_episodes(bench.episodes_file(ROWS, "request", tmp_path / "request.jsonl"))
    assert [s.instruction for s in specs] == [r["request"] for r in ROWS]
    assert [s.description for s in specs] == [r["fields"] for r in ROWS]


def test_a_generator_episode_is_written_as_before(tmp_path):
    path = bench.episodes_file(ROWS, "generator", tmp_path / "generator.jsonl")
    specs = load_episodes(path)
    assert [s.to_dict() for s in specs] == [r["spec"] for r in ROWS]
    assert all(s.description is None for s in specs) and "description" not in path.read_text()
