"""``vla-gr eval`` on absent-object episodes: rows carry ``absent`` and
``declared_not_found``, a STOP there is a false STOP told apart by what it was next to, and
metrics.json and the report count them apart from the normal episodes."""

from __future__ import annotations

import json

import numpy as np

from tests.test_eval import FAST, rows_of
from tests.test_evaluate import DeclaresAfter, Scripted
from vla_gr.envs.absent import sample_absent_episode
from vla_gr.envs.episodes import sample_episode, save_episodes
from vla_gr.evaluate import run_from_cli
from vla_gr.evaluation import AGENTS
from vla_gr.evaluation.agents import PolicyAgent
from vla_gr.evaluation.causes import WRONG_STOP_KINDS


def test_eval_counts_absent_episodes_apart_and_a_normal_not_found_as_a_failure(
    tmp_path, monkeypatch, capsys
):
    absent, normal = sample_absent_episode("val", 0, num_rooms=2), sample_episode("val", 0)
    file = save_episodes(tmp_path / "absent.jsonl", [absent, normal])
    monkeypatch.setitem(
        AGENTS, "declares", lambda cfg, env: PolicyAgent(DeclaresAfter("not_found", 2))
    )
    out = tmp_path / "run"
    args = [f"output_dir={out}", *FAST, "eval.video_per_cause=1", "agent=declares",
            f"episodes={file}", "env.max_episode_steps=5", "env.image_size=16"]  # fmt: skip
    assert run_from_cli("config_debug", args) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1] == (
        "absent objects (1 episodes, not in SR / SPL): declared not found 1, false STOPs 0, "
        "timeouts 0, median steps to declare 2"
    )
    a, n = rows_of(out)
    assert a["absent"] is True and a["declared_not_found"] is True and a["cause"] == "not_found"
    assert a["spec"]["absent"] is True and a["metrics"]["distance_to_goal"] == np.inf
    assert n["absent"] is False and n["declared_not_found"] is True and n["cause"] == "not_found"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["metrics"]["episodes"] == 1 and metrics["metrics"]["success"] == 0.0
    assert metrics["failure_causes"]["not_found"] == 1  # the normal episode's: a failure
    assert metrics["declared"] == {"not_understood": 0, "not_found": 1}
    block = metrics["absent_objects"]
    assert (block["episodes"], block["declared_not_found"], block["false_stops"]) == (1, 1, 0)
    assert block["steps_to_declare"]["median"] == 2.0
    report = (out / "report.md").read_text()
    assert "## Absent objects" in report and "| 1 (100.0%) | 0 (0.0%) | 0 | 0 | 2 |" in report
    assert (out / "episode_0000_not_found_topdown.png").is_file()  # pictured without a goal


def test_a_run_of_absent_episodes_alone_writes_its_report(tmp_path, monkeypatch):
    file = save_episodes(tmp_path / "absent.jsonl", [sample_absent_episode("val", 0, num_rooms=1)])
    monkeypatch.setitem(
        AGENTS, "declares", lambda cfg, env: PolicyAgent(DeclaresAfter("not_found", 2))
    )
    out = tmp_path / "run"
    args = [f"output_dir={out}", *FAST, "agent=declares", f"episodes={file}",
            "env.max_episode_steps=5", "env.image_size=16"]  # fmt: skip
    assert run_from_cli("config_debug", args) == 0
    report = (out / "report.md").read_text()
    assert "(no normal episode)" in report and "## Absent objects" in report


def test_a_stop_in_an_absent_episode_is_a_false_stop_named_by_what_it_was_next_to():
    from vla_gr.data.collect import make_env
    from vla_gr.evaluation.runner import run_episode

    spec = sample_absent_episode("val", 0, num_rooms=2)
    env = make_env({"split": "val", "image_size": 16, "episodes": [spec]})
    try:
        row = run_episode(env, PolicyAgent(Scripted([0.0, 0.0, 1.0])), 0)
    finally:
        env.close()
    assert row["stopped"] and row["absent"] and not row["declared_not_found"]
    assert row["metrics"]["success"] == 0.0 and row["metrics"]["steps"] == 1
    assert row["cause"] in ("stopped_at_distractor", "stopped_elsewhere")
    assert row["wrong_stop"] in WRONG_STOP_KINDS and row["stopped_near"]["instance_id"] > 0
    house = env.unwrapped.house
    asked = {o.instance_id for o in house.objects if o.category == spec.goal_category}
    assert {int(k) for k in row["distractor_distances"]} == asked  # every one of the category
