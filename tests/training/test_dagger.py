"""DAgger data: an eval run's own states replayed with their true masks and aggregated."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vla_gr.configs import load_config
from vla_gr.data.collect import collect
from vla_gr.data.store import EpisodeStore
from vla_gr.errors import UserError
from vla_gr.evaluate import evaluate, expand_aliases
from vla_gr.training.dagger import aggregate, relabelled_records


def _run(tmp_path, split: str, first: int = 0):
    out = tmp_path / f"run-{split}-{first}"
    args = [f"output_dir={out}", "agent=random", f"split={split}", "num_episodes=2",
            f"first_episode={first}",
            "eval.progress=false", "eval.video_successes=0", "eval.video_per_cause=0"]  # fmt: skip
    cfg = load_config("config_debug", [*expand_aliases(args), "env.max_episode_steps=25"])[1]
    evaluate(cfg)
    return out


def test_replayed_frames_are_the_agents_own_with_true_masks(tmp_path):
    run = _run(tmp_path, "train")
    rows = [json.loads(x) for x in (run / "episodes.jsonl").read_text().splitlines()]
    records = list(relabelled_records(run))
    assert [r.episode_index for r in records] == [row["episode_index"] for row in rows]
    for record, row in zip(records, rows):
        assert len(record) == len(row["actions"])  # one frame per decision the agent made
        np.testing.assert_allclose(record.action, np.clip(row["actions"], -1, 1), atol=1e-6)
        assert not (record.goal_mask & record.distractor_mask).any()
        assert record.instruction == row["spec"]["instruction"]


def test_aggregate_appends_to_a_copy_and_refuses_eval_splits(tmp_path):
    base = tmp_path / "base.zarr"
    cfg = load_config(
        "config_debug",
        [f"collect.output={base}", "collect.num_episodes=1", "env.max_episode_steps=20"],
    )[1]
    collect(cfg)
    with pytest.raises(UserError, match="already holds train episodes"):
        aggregate(_run(tmp_path, "train"), base, tmp_path / "agg.zarr")  # episode 0 is in base
    run = _run(tmp_path, "train", first=5)
    summary = aggregate(run, base, tmp_path / "agg.zarr")
    agg, src = EpisodeStore.open(tmp_path / "agg.zarr"), EpisodeStore.open(base)
    assert summary["added_episodes"] == 2 and agg.num_episodes == src.num_episodes + 2
    assert agg.num_frames == src.num_frames + summary["added_frames"]
    with pytest.raises(UserError, match="exists"):
        aggregate(run, base, tmp_path / "agg.zarr")
    with pytest.raises(UserError, match="train episodes only"):
        next(relabelled_records(_run(tmp_path, "val")))
