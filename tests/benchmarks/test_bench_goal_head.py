"""bench_goal_head: scoring against hand counts on a tiny store, kinds, latency, end to end."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers import train_overrides
from vla_gr.configs import load_config
from vla_gr.data.store import EpisodeStore, fake_episode
from vla_gr.train import train

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_goal_head.py"
_spec = importlib.util.spec_from_file_location("bench_goal_head", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

INSTRUCTIONS = (
    "find the red chair",
    "go to the bed in the kitchen",
    "find the sofa next to the tv",
    "find the blue bed in the bedroom",
)


@pytest.fixture
def store(tmp_path):
    store = EpisodeStore.create(tmp_path / "s.zarr", image_size=8)
    for i, text in enumerate(INSTRUCTIONS):
        rec = fake_episode(i, 3 + i)
        rec.instruction = text
        store.append(rec)
    return EpisodeStore.open(tmp_path / "s.zarr")


def test_instruction_kinds():
    kinds = [bench.instruction_kind(t) for t in INSTRUCTIONS]
    assert kinds == ["colour", "room", "relation", "colour+room"]
    assert bench.instruction_kind("find the chair") == "category"


def test_all_goal_predictor_scores_match_hand_counts(store):
    """Predicting every pixel as goal: recall 1, precision = goal share, on distractor =
    distractor share; the kinds partition the frames."""

    def everything(rgb, depth, instructions):
        B, _, H, W = rgb.shape
        return torch.ones(B, H, W), torch.ones(B)

    result = bench.score_store(everything, store, threshold=0.5, min_pixels=4, batch_size=5)
    goal = sum(store.episode(e)["goal_mask"].sum() for e in range(4))
    others = sum(store.episode(e)["distractor_mask"].sum() for e in range(4))
    pixels = store.num_frames * 64
    overall = result["overall"]
    assert overall["pixel_recall"] == 1.0
    assert overall["pixel_precision"] == pytest.approx(goal / pixels)
    assert overall["on_distractor"] == pytest.approx(others / pixels)
    visible = sum((store.episode(e)["goal_mask"].sum((1, 2)) >= 4).sum() for e in range(4))
    assert overall["visible_accuracy"] == pytest.approx(visible / store.num_frames)
    assert set(result["by_kind"]) == {"colour", "room", "relation", "colour+room"}
    assert result["by_kind"]["room"]["counts"]["frames"] == 4  # episode 1 has 4 frames
    for key, n in overall["counts"].items():
        assert sum(k["counts"][key] for k in result["by_kind"].values()) == n, key
    text = bench.table(result | {"latency": {"threads": 1, "p50_ms": 1.0, "p95_ms": 2.0}})
    rows = [line for line in text.splitlines() if line.startswith("| ")]
    assert len(rows) == 6 and rows[1].startswith("| all | 4 |")  # header, all, 4 kinds


def test_a_category_output_is_scored_against_goal_or_distractors(store):
    """A category output that marks exactly the distractors: precision 1 and recall =
    distractor pixels / (goal + distractor pixels), since the goal pixels are missed."""

    def distractors_only(rgb, depth, instructions):
        B, _, H, W = rgb.shape
        return torch.zeros(B, H, W), torch.zeros(B), torch.from_numpy(truth)  # one batch

    episodes = [store.episode(e) for e in range(4)]
    goal = sum(int(ep["goal_mask"].sum()) for ep in episodes)
    others = sum(int(ep["distractor_mask"].sum()) for ep in episodes)
    assert goal > 0 and others > 0
    truth = np.concatenate([ep["distractor_mask"] for ep in episodes]).astype(np.float32)
    result = bench.score_store(distractors_only, store, 0.5, 4, batch_size=store.num_frames)
    assert result["category"]["pixel_precision"] == 1.0
    assert result["category"]["pixel_recall"] == pytest.approx(others / (goal + others))
    assert "category" not in result["by_kind"]
    text = bench.table(result | {"latency": {"threads": 1, "p50_ms": 1.0, "p95_ms": 2.0}})
    assert "Category output" in text and "precision 1.000" in text


def test_checkpoint_end_to_end_collects_scores_and_writes(tmp_path):
    overrides = {
        "model.agent": "dual_system",
        "model.goal_head.text_encoder": "hashed",
        "training.steps": 1,
        "training.run_name": "r",
    }
    resolved, cfg = load_config("config_debug", train_overrides(tmp_path, **overrides))
    train(cfg, resolved)
    checkpoint = tmp_path / "runs" / "r" / "checkpoints" / "latest"
    out = tmp_path / "results" / "bench"
    argv = ["--checkpoint", str(checkpoint), "--episodes", "1", "--workers", "1"]
    argv += ["--repeats", "3", "--store", str(tmp_path / "val.zarr"), "--out", str(out)]
    result = bench.main(argv)
    store = EpisodeStore.open(tmp_path / "val.zarr")
    assert store.info["split"] == "val" and store.episode_indices.tolist() == [0]
    assert result["overall"]["counts"]["frames"] == store.num_frames
    assert result["latency"]["p50_ms"] > 0 and result["latency"]["threads"] == 1
    saved = json.loads(out.with_suffix(".json").read_text())
    assert saved["overall"]["counts"] == result["overall"]["counts"]
    assert "| all | 1 |" in out.with_suffix(".md").read_text()
