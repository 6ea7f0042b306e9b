"""paraphrase_readings: each episode in the group its reading falls in."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "paraphrase_readings.py"
_spec = importlib.util.spec_from_file_location("paraphrase_readings", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

SAID = "Find the red chair in the kitchen near the tv"


@pytest.mark.parametrize(
    "read, group",
    [
        ("find the red chair in the kitchen next to the tv", "every field right"),
        ("find the red chair next to the tv", "a field left empty"),  # no room
        ("find the red chair in the kitchen next to the couch", "a field left empty"),
        ("find the red chair in the kitchen next to the bed", "a wrong category or anchor"),
        ("find the red sofa in the kitchen next to the tv", "a wrong category or anchor"),
        ("find the red sofa in the office next to the tv", "a wrong room"),  # room first
    ],
)
def test_a_reading_falls_in_the_first_group_that_fits(read, group):
    assert bench.reading_group(SAID, read) == group


def test_the_table_counts_episodes_and_successes(tmp_path, capsys, monkeypatch):
    def write(folder, rows):
        folder.mkdir()
        (folder / "episodes.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")

    def row(i, text, success, read_as=None):
        agent = {"read_as": read_as} if read_as else {}
        return {"episode_index": i, "spec": {"instruction": text},
                "metrics": {"success": success}, "agent": agent}  # fmt: skip

    write(tmp_path / "clean", [row(0, SAID, 1.0), row(1, SAID, 1.0), row(2, SAID, 1.0)])
    write(tmp_path / "para", [
        row(0, "go into the kitchen and find the chair that is red beside the television", 1.0,
            "find the red chair in the kitchen next to the tv"),
        row(1, "the red seat close to the telly", 0.0, "find the red chair next to the bed"),
        row(2, "find the red chair in the kitchen near the tv", 0.0),  # read as it was
    ])  # fmt: skip
    monkeypatch.setattr("sys.argv", ["x", str(tmp_path / "clean"), str(tmp_path / "para")])
    bench.main()
    out = capsys.readouterr().out
    assert "| every field right | 2 | 0.500 |" in out
    assert "| a wrong category or anchor | 1 | 0.000 |" in out
    assert "| a wrong room | 0 | |" in out


def test_without_a_clean_run_the_template_instruction_is_drawn_again(tmp_path, capsys, monkeypatch):
    from vla_gr.envs.episodes import sample_episode

    said = sample_episode("val", 3).instruction
    rows = [  # read as the template said it, and as another instruction
        {"episode_index": 3, "spec": {"instruction": "x", "split": "val"},
         "metrics": {"success": 1.0}, "agent": {"read_as": said}},
        {"episode_index": 4, "spec": {"instruction": "x", "split": "val"},
         "metrics": {"success": 0.0}, "agent": {"read_as": said}},
    ]  # fmt: skip
    (tmp_path / "para").mkdir()
    (tmp_path / "para" / "episodes.jsonl").write_text("\n".join(map(json.dumps, rows)) + "\n")
    monkeypatch.setattr("sys.argv", ["x", str(tmp_path / "para")])
    bench.main()
    out = capsys.readouterr().out
    assert "| every field right | 1 | 1.000 |" in out
    assert sample_episode("val", 4).instruction != said  # episode 4 said something else
    assert "| every field right | 2 |" not in out
