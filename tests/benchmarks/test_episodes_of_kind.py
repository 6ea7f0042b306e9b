"""episodes_of_kind: the split's own episodes of one instruction kind, in index order."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from vla_gr.envs.episodes import load_episodes, sample_episode, save_episodes
from vla_gr.evaluation.runner import instruction_kind

_ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location(
    "episodes_of_kind", _ROOT / "benchmarks" / "episodes_of_kind.py"
)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_the_kept_episodes_are_the_splits_own_of_that_kind_and_match_the_committed_file(tmp_path):
    kept, counts = bench.episodes_of_kind("val", 1000, 1030, "relation")
    assert sum(counts.values()) == 30 and counts["relation"] == len(kept) > 0
    assert all(instruction_kind(s.instruction) == "relation" for s in kept)
    indices = [int(s.episode_id.split("-")[1]) for s in kept]
    assert indices == sorted(indices) and all(1000 <= i < 1030 for i in indices)
    assert kept[0] == sample_episode("val", indices[0])  # the environment's spec, unchanged
    # the committed relation set starts with exactly these episodes
    committed = load_episodes(_ROOT / "docs/experiments/eval/episodes/val_relation_1000-1799.jsonl")
    assert committed[: len(kept)] == kept
    assert load_episodes(save_episodes(tmp_path / "e.jsonl", kept)) == kept


def test_an_unknown_kind_is_refused_naming_the_choices():
    with pytest.raises(ValueError, match="relation, room, colour, category"):
        bench.episodes_of_kind("val", 0, 1, "colours")
