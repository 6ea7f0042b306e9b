"""blind_sets: an episodes file of a request set carries the generator's fields."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from vla_gr.envs.episodes import EpisodeSpec, load_episodes

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "language" / "blind_sets.py"
_spec = importlib.util.spec_from_file_location("blind_sets", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def _row(index: int, instruction: str, fields: dict, request: str) -> dict:
    spec = EpisodeSpec(
        f"test-{index:06d}", "test", 7, 2, 1.0, 1.0, 2.0, 0.5, 4, fields["category"],
        instruction, 3.0,
    )  # fmt: skip
    return {"spec": spec.to_dict(), "fields": fields, "request": request}


ROWS = [
    _row(
        0,
        "find the red chair in the kitchen",
        {"category": "chair", "color": "red", "room": "kitchen", "near": None},
        "that red seat in the kitchen, please",
    ),
    _row(
        1,
        "go to the bed next to the plant",
        {"category": "bed", "color": None, "room": None, "near": "plant"},
        "the bed by the plant \u2014 thanks!",
    ),
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
