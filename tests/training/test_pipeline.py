"""The staged training app: ``recipe_debug`` runs every stage kind once; a second run skips
the stages whose outputs record the same inputs and settings; a changed setting reruns that
stage and those after it (or is refused, naming it); an interrupted stage resumes."""

from __future__ import annotations

from pathlib import Path

import pytest

from vla_gr.configs import ConfigError, load_config
from vla_gr.configs.pipeline_schema import STAGE_KINDS
from vla_gr.data.store import EpisodeStore
from vla_gr.evaluation.harness import evaluate
from vla_gr.policy import VLAGRPolicy, load_policy
from vla_gr.train import train
from vla_gr.training.pipeline import StageError, run_pipeline, tree_digest
from vla_gr.training.stages import STAGES, Services, check_kinds

SERVICES = Services(train=train, evaluate=evaluate)


def _run(out: Path, *overrides: str) -> dict[str, dict]:
    resolved, cfg = load_config(
        "recipe_debug", [f"pipeline.output_dir={out}", "training.output_dir=unused", *overrides]
    )
    return run_pipeline(resolved, cfg, SERVICES)


def test_every_kind_of_the_schema_has_a_stage():
    check_kinds(STAGE_KINDS)
    assert set(STAGES) == set(STAGE_KINDS)


def test_recipe_runs_every_stage_then_skips_reruns_and_refuses(tmp_path, caplog):
    out = tmp_path / "pipe"
    first = _run(out)
    assert list(first) == [
        "expert", "more", "goal_head", "rollouts", "dagger", "finetune", "s1_data", "s1",
        "shipped",
    ]  # fmt: skip
    more = EpisodeStore.open(first["more"]["product"])
    assert sorted(more.episode_indices.tolist()) == [0, 1, 20]  # the copy + one appended
    assert first["finetune"]["product"].endswith("step_00000002")  # use: latest
    shipped = load_policy(first["shipped"]["product"])
    assert type(shipped) is VLAGRPolicy and shipped.config.s1.kind == "pure_pursuit"
    for name, record in first.items():
        assert record["product_sha256"] == tree_digest(Path(record["product"])), name
        assert record["seconds"] >= 0 and len(record["attempts"]) == 1
    # the fine-tune starts from the goal head and reads the DAgger store
    assert first["finetune"]["inputs"] == {
        "dagger": first["dagger"]["product_sha256"],
        "goal_head": first["goal_head"]["product_sha256"],
    }

    caplog.set_level("INFO")
    again = _run(out, "eval.video_all=true", "training.eval_videos=3", "eval.workers=2")
    assert again == first  # nothing reran (which episodes are filmed, and by how many
    # workers, change no product): every record is the same, timings included
    assert caplog.text.count("up to date") == len(first)

    # a setting of the fine-tune changes: it and every stage after it that reads it rerun
    caplog.clear()
    changed = _run(out, "pipeline.stages.5.overrides=['training.lr=0.0005']")
    rerun = [n for n in first if changed[n]["attempts"] != first[n]["attempts"]]
    assert rerun == ["finetune", "s1", "shipped"]
    assert "finetune: settings changed" in caplog.text
    with pytest.raises(StageError, match=r"stage finetune: .* made with other settings"):
        _run(out, "pipeline.on_stale=refuse")


TWO = (
    "pipeline.stages=[{name:expert,kind:collect,overrides:['collect.num_episodes=2']},"
    "{name:goal_head,kind:train,inputs:[expert]}]"
)


def test_an_interrupted_stage_runs_again_and_resumes(tmp_path, caplog):
    out = tmp_path / "pipe"
    first = _run(out, TWO)
    (out / "goal_head" / "stage.json").unlink()  # as if killed after its last checkpoint
    caplog.set_level("INFO")
    again = _run(out, TWO)
    assert "stage expert: up to date" in caplog.text
    assert "already finished at step 2" in caplog.text  # resumed from latest: nothing to train
    assert again["goal_head"]["product_sha256"] == first["goal_head"]["product_sha256"]


def test_a_bad_recipe_fails_before_any_work_naming_the_stage(tmp_path):
    with pytest.raises(ConfigError, match=r"pipeline.stages\[goal_head\].inputs names 'nope'"):
        load_config("recipe_debug", ["pipeline.stages.2.inputs=[nope]"])
    with pytest.raises(ConfigError, match=r"pipeline.stages\[\w+\].kind"):
        load_config("recipe_debug", ["pipeline.stages.0.kind=bake"])
    with pytest.raises(StageError, match=r"pipeline.stages\[expert\].overrides \(collect.nope\)"):
        _run(tmp_path / "p", "pipeline.stages.0.overrides=['collect.nope=1']")
    assert not (tmp_path / "p" / "expert" / "stage.json").exists()
