"""``vla-gr eval``: agents on episodes, metrics.json vs episodes.jsonl, workers, resume,
failure causes from scripted agents, and one-line refusals of bad input."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from vla_gr.agent.dual_system import GroundedDualSystem
from vla_gr.agent.perception.percept import Percept
from vla_gr.cli import main as cli_main
from vla_gr.configs import load_config
from vla_gr.evaluate import EvalInputError, evaluate, expand_aliases, run_from_cli
from vla_gr.evaluation import AGENTS
from vla_gr.evaluation.agents import EvalAgent, UntrainedDualSystemAgent, register_agent
from vla_gr.evaluation.summary import BREAKDOWNS, without_timing

FAST = ["eval.progress=false", "eval.video_successes=1", "eval.video_per_cause=0", "seed=3"]


def cfg_for(out: Path, *overrides: str):
    args = expand_aliases([f"output_dir={out}", *FAST, *overrides])
    return load_config("config_debug", args)[1]


def rows_of(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "episodes.jsonl").read_text().splitlines()]


def no_latency(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "latency_ms"} for r in rows]


class Constant(EvalAgent):
    """A scripted agent: the same action every step."""

    def __init__(self, action) -> None:
        self.action = np.asarray(action, dtype=np.float32)

    def act(self, obs) -> np.ndarray:
        return self.action


def test_expert_reaches_every_goal_random_does_worse_and_metrics_match_the_rows(tmp_path, caplog):
    out = tmp_path / "expert"
    metrics = evaluate(cfg_for(out, "agent=expert", "num_episodes=3", "env.max_episode_steps=500"))
    assert metrics["metrics"]["success"] == 1.0 and metrics["metrics"]["episodes"] == 3
    on_disk = json.loads((out / "metrics.json").read_text())
    rows = rows_of(out)
    assert [r["episode_index"] for r in rows] == [0, 1, 2]
    for key in ("success", "spl", "soft_spl", "distance_to_goal", "path_length", "steps"):
        assert on_disk["metrics"][key] == pytest.approx(np.mean([r["metrics"][key] for r in rows]))
    for key in BREAKDOWNS:
        groups = on_disk["breakdowns"][key]
        assert sum(g["episodes"] for g in groups.values()) == 3
        for value, g in groups.items():
            sub = [r for r in rows if str(r[key]) == value]
            assert g["success"] == pytest.approx(np.mean([r["metrics"]["success"] for r in sub]))
    assert sum(on_disk["failure_causes"].values()) == 0
    assert on_disk["env"]["depth_noise_std"] == 0.0 and on_disk["env"]["actuation_noise"] == 0.0
    assert on_disk["latency_ms"]["decision"]["calls"] == sum(len(r["actions"]) for r in rows)
    assert all(len(r["trace"]["xy"]) == r["metrics"]["steps"] + 1 for r in rows)
    assert (out / "report.md").is_file() and (out / "breakdowns.png").is_file()
    assert (out / "report.html").is_file()
    assert len(list(out.glob("*.mp4"))) == 1 and len(list(out.glob("*_topdown.png"))) == 1

    noisy = ("env.depth_noise_std=0.05", "env.actuation_noise=0.2")
    cfg = cfg_for(tmp_path / "rand", "agent=random", "num_episodes=3", *noisy)
    cfg = dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, video_per_cause=1))
    with caplog.at_level(logging.WARNING):
        rand = evaluate(cfg)
    assert list((tmp_path / "rand").glob("*.mp4"))  # replayed with the same noise draws:
    assert "replay ended elsewhere" not in caplog.text  # every replay ends where the run did
    assert rand["env"]["depth_noise_std"] == 0.05 and rand["env"]["actuation_noise"] == 0.2
    assert rand["metrics"]["success"] < 1.0
    assert sum(rand["failure_causes"].values()) == 3 - round(3 * rand["metrics"]["success"])
    assert all(math.isfinite(r["metrics"]["distance_to_goal"]) for r in rows_of(tmp_path / "rand"))


def test_results_do_not_depend_on_the_number_of_workers(tmp_path):
    common = ("agent=random", "num_episodes=3", "env.max_episode_steps=25")
    one = evaluate(cfg_for(tmp_path / "w1", *common, "workers=1"))
    two = evaluate(cfg_for(tmp_path / "w2", *common, "workers=2"))
    assert without_timing(one) == without_timing(two)
    assert no_latency(rows_of(tmp_path / "w1")) == no_latency(rows_of(tmp_path / "w2"))
    assert two["timing"]["workers"] == 2
    assert two["timing"]["machine"]["cores"] == os.cpu_count()  # the eval time's context


def test_a_killed_run_resumes_from_its_finished_rows(tmp_path):
    common = ("agent=random", "num_episodes=3", "env.max_episode_steps=25")
    straight = evaluate(cfg_for(tmp_path / "straight", *common))
    part = tmp_path / "part"
    part.mkdir()
    shutil.copy(tmp_path / "straight" / "run.json", part / "run.json")
    lines = (tmp_path / "straight" / "episodes.jsonl").read_text().splitlines()
    (part / "episodes.jsonl").write_text(lines[0] + "\n" + lines[1][:50])  # torn second row
    resumed = evaluate(cfg_for(part, *common))
    assert without_timing(resumed) == without_timing(straight)
    assert resumed["timing"]["episodes_run"] == 2 and straight["timing"]["episodes_run"] == 3
    rows = rows_of(part)
    assert json.dumps(rows[0]) == lines[0]  # kept as written (same latency): not re-run
    assert no_latency(rows) == no_latency(rows_of(tmp_path / "straight"))
    # a different setting in the same folder is refused instead of mixed in
    with pytest.raises(EvalInputError, match="holds a run with agent='random'"):
        run_from_cli("config_debug", [f"output_dir={part}", "agent=expert", *FAST])


def test_an_index_whose_house_hosts_no_episode_is_skipped_and_named(tmp_path, caplog):
    from vla_gr.envs.episodes import NoEpisodeError, sample_episode

    # val 3956-3959 share house 1000989, whose objects have no unique description
    with pytest.raises(NoEpisodeError, match="house 1000989"):
        sample_episode("val", 3956)
    out = tmp_path / "skip"
    args = ("agent=random", "split=val", "first_episode=3955", "num_episodes=2",
            "env.max_episode_steps=5")  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="vla_gr.evaluation.harness"):
        metrics = evaluate(cfg_for(out, *args))
    assert "1 of 2 episode indices skipped" in caplog.text
    assert metrics["num_episodes"] == 2 and metrics["metrics"]["episodes"] == 1
    assert list(metrics["skipped_episodes"]) == ["3956"]
    assert "house 1000989 has no goal candidates" in metrics["skipped_episodes"]["3956"]
    assert [r["episode_index"] for r in rows_of(out)] == [3955]
    assert metrics["timing"]["episodes_run"] == 1
    # a rerun in the same folder resumes the one episode and skips the other again
    again = evaluate(cfg_for(out, *args))
    assert again["timing"]["episodes_run"] == 0 and without_timing(again) == without_timing(metrics)


# ----------------------------------------------------------------------------- failure causes


def _scripted_episodes(path: Path) -> None:
    """Episodes in val house 0: start at a distractor, facing the goal, facing away."""
    from vla_gr.envs.episodes import EpisodeSpec, sample_episode, save_episodes
    from vla_gr.envs.geodesic import goal_distance_field, sample_field, traversable_cells
    from vla_gr.envs.house import generate_house
    from vla_gr.envs.instructions import distractors

    base = sample_episode("val", 0)
    house = generate_house(base.scene_seed)
    goal = house.object(base.goal_instance_id)
    to_goal = goal_distance_field(house, goal.instance_id)  # (H, W)
    to_other = goal_distance_field(house, distractors(house, goal.instance_id)[0])
    free = traversable_cells(house)
    rows, cols = np.nonzero(free & np.isfinite(to_goal))
    xy = house.grid.cell_to_world(np.stack([rows, cols], axis=1))  # (N, 2)
    g = np.array([sample_field(to_goal, house.grid, x, y) for x, y in xy])
    o = np.array([sample_field(to_other, house.grid, x, y) for x, y in xy])

    def spec(i: int, name: str, face_goal: bool) -> EpisodeSpec:
        x, y = xy[i]
        yaw = math.atan2(goal.y - y, goal.x - x) + (0.0 if face_goal else math.pi)
        fields = dict(base.to_dict(), episode_id=name, start_x=x, start_y=y, start_yaw=yaw)
        return EpisodeSpec(**dict(fields, geodesic_start_distance=float(g[i])))

    at_distractor = int(np.flatnonzero((o < 0.5) & (g > 2.0))[0])
    near_goal = np.flatnonzero((g > 1.3) & (g < 1.8))
    straight = np.hypot(*(xy[near_goal] - [goal.x, goal.y]).T) - max(goal.half_extents)
    near_goal = int(near_goal[np.argmin(np.abs(g[near_goal] - straight))])  # clear view
    specs = [
        spec(at_distractor, "at-distractor", False),
        spec(near_goal, "facing-goal", True),
        spec(near_goal, "facing-away", False),
    ]
    save_episodes(path, specs)


def test_each_failure_cause_comes_from_an_agent_built_to_cause_it(tmp_path, monkeypatch):
    file = tmp_path / "scripted.jsonl"
    _scripted_episodes(file)
    agents = {
        "stop": Constant([0.0, 0.0, 1.0]),
        "spin": Constant([0.0, 1.0, -1.0]),
        "still": Constant([0.0, 0.0, -1.0]),
    }
    for name, agent in agents.items():
        monkeypatch.setitem(AGENTS, name, lambda cfg, env, a=agent: a)
    common = (f"episodes={file}", "env.max_episode_steps=30", "eval.goal_seen_pixels=5")

    rows: dict[str, dict] = {}

    def causes(agent: str, *extra: str) -> dict[str, str]:
        out = tmp_path / f"{agent}{len(extra)}"
        evaluate(cfg_for(out, f"agent={agent}", *common, *extra))
        rows.update({f"{agent}/{r['episode_id']}": r for r in rows_of(out)})
        return {r["episode_id"]: r["cause"] for r in rows_of(out)}

    stop = causes("stop")
    assert stop["at-distractor"] == "stopped_at_distractor"
    assert stop["facing-goal"] == stop["facing-away"] == "stopped_elsewhere"
    near = rows["stop/at-distractor"]["stopped_near"]  # the distractor it stopped beside
    assert near["category"] == rows["stop/at-distractor"]["goal_category"]
    assert near["distance"] < 0.5 and rows["stop/at-distractor"]["wrong_stop"] == "same_category"
    assert all(r["wrong_stop"] is not None for r in rows.values())
    assert set(causes("spin", "eval.stuck_steps=20").values()) == {"stuck"}
    still = causes("still", "eval.stuck_steps=100")  # never "stuck": window > budget
    assert still["facing-goal"] == "timeout_goal_seen"
    assert still["facing-away"] == "timeout_goal_never_seen"
    assert rows["still/facing-goal"]["stopped_near"] == {}  # no STOP: nothing to explain
    assert rows["still/facing-goal"]["wrong_stop"] is None


class RejectsThreeGoals(Constant):
    """Stands still and reports three rejected goals (in the episode-start frame): on the goal
    instance, on a same-category distractor, and 3 m behind the start (nothing there)."""

    def __init__(self, env) -> None:
        super().__init__([0.0, 0.0, -1.0])
        self.env = env

    def episode_summary(self) -> dict:
        from vla_gr.envs.instructions import distractors
        from vla_gr.geometry.pose2d import map_to_robot

        u = self.env.unwrapped
        other = u.house.object(distractors(u.house, u.goal.instance_id)[0])
        world = np.array([[u.goal.x, u.goal.y], [other.x, other.y]])  # (2, 2) object centres
        start = map_to_robot(world, u.start_pose_world)  # (2, 2) episode-start frame
        xy = [*start.tolist(), [-3.0, 0.0]]
        reasons = ["trap", "room", "verify"]
        return {"rejections": [{"reason": r, "xy": p} for r, p in zip(reasons, xy)]}


def test_rejected_goals_are_named_by_the_object_they_lay_on(tmp_path, monkeypatch):
    file = tmp_path / "scripted.jsonl"
    _scripted_episodes(file)
    monkeypatch.setitem(AGENTS, "rejects", lambda cfg, env: RejectsThreeGoals(env))
    out = tmp_path / "rejects"
    metrics = evaluate(cfg_for(out, "agent=rejects", f"episodes={file}", *SHORT))
    row = rows_of(out)[1]  # facing-goal: 3 m behind it lies open floor
    assert [g["kind"] for g in row["rejected_goals"]] == ["goal", "same_category", "other_object"]
    assert row["rejected_goals"][0]["near"]["instance_id"] == row["spec"]["goal_instance_id"]
    assert metrics["rejected_goals"]["trap"] == {"goal": 3, "same_category": 0, "other_object": 0}
    assert metrics["rejected_goals"]["room"]["same_category"] == 3
    assert metrics["rejected_goals"]["episodes_failed_after_rejecting_the_goal"] == 3
    assert "Failed episodes that had rejected the goal itself: 3" in (out / "report.md").read_text()


# ------------------------------------------------------------------ checkpoints, bad input


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    from vla_gr import cli

    tmp = tmp_path_factory.mktemp("ckpt")
    args = [
        f"training.dataset={tmp / 'syn.zarr'}",
        f"training.output_dir={tmp / 'runs'}",
        "training.run_name=r",
        "logging.tensorboard=false",
    ]
    assert cli.main(["train", "--config-name", "config_debug", *args]) == 0
    return tmp / "runs" / "r" / "checkpoints" / "best"


def test_a_trained_checkpoint_reports_latency_and_parameters(tmp_path, checkpoint):
    from vla_gr.policy import load_policy

    # no agent= given: a checkpoint= means the checkpoint agent
    metrics = evaluate(
        cfg_for(tmp_path, f"checkpoint={checkpoint}", "num_episodes=2", "env.max_episode_steps=8")
    )
    assert metrics["agent"] == "checkpoint"
    policy = load_policy(checkpoint)
    assert metrics["parameters"]["total"] == sum(p.numel() for p in policy.parameters())
    assert metrics["parameters"]["head"] == sum(p.numel() for p in policy.head.parameters())
    lat = metrics["latency_ms"]["decision"]
    assert 0 < lat["p50"] <= lat["p95"] <= lat["p99"]
    assert metrics["checkpoint"] == str(checkpoint)


def test_a_run_on_a_checkpoint_rewritten_in_place_is_not_resumed(tmp_path, checkpoint):
    from vla_gr.policy.export import export_pretrained

    ckpt, out = tmp_path / "agent", tmp_path / "run"
    export_pretrained(checkpoint, ckpt)
    args = (f"checkpoint={ckpt}", "num_episodes=1", "env.max_episode_steps=8")
    first = evaluate(cfg_for(out, *args))
    assert first["checkpoint_digest"] and len(first["checkpoint_digest"]) == 64
    assert evaluate(cfg_for(out, *args))["checkpoint_digest"] == first["checkpoint_digest"]
    export_pretrained(checkpoint, ckpt, ["navigator.confirmation.ticks=4"])  # same path, new agent
    with pytest.raises(EvalInputError, match="checkpoint_digest"):
        evaluate(cfg_for(out, *args))


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["agent=nope"], "valid agents: checkpoint, expert, random"),
        (["workers=0"], "eval.workers=0 must be >= 1"),
        (["agent=checkpoint"], "agent=checkpoint needs checkpoint="),
        (["agent=checkpoint", "checkpoint=/no/such/run"], "/no/such/run does not exist"),
        (["agent=checkpoint", "CKPT", "env.image_size=64"], "model.image_size=32"),
        (["agent=expert", "episodes=BAD"], "bad.jsonl:2: bad episode record"),
        (["agent=expert", "episodes=GOOD", "num_episodes=5"], "exceeds the 1 episodes"),
        (["agent=expert", "episodes=ELSE"], "else.jsonl:1: instruction 'go to the fridge' does"),
    ],
)
def test_bad_input_is_one_line_before_any_episode(tmp_path, capsys, checkpoint, overrides, message):
    from vla_gr.envs.episodes import sample_episode, save_episodes

    good = save_episodes(tmp_path / "good.jsonl", [sample_episode("val", 0)])
    fridge = dataclasses.replace(sample_episode("val", 0), instruction="go to the fridge")
    save_episodes(tmp_path / "else.jsonl", [fridge])  # words that describe no goal
    bad = tmp_path / "bad.jsonl"
    bad.write_text(good.read_text() + '{"episode_id": "x"}\n')
    subs = {"CKPT": f"checkpoint={checkpoint}", "episodes=BAD": f"episodes={bad}"}
    subs["episodes=GOOD"] = f"episodes={good}"
    subs["episodes=ELSE"] = f"episodes={tmp_path / 'else.jsonl'}"
    args = [subs.get(o, o) for o in overrides]
    out = tmp_path / "out"
    argv = ["eval", "--config-name", "config_debug", f"output_dir={out}", *FAST, *args]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vla-gr eval: error:") and message in err, err
    assert len(err.splitlines()) <= 2 and "Traceback" not in err
    assert not out.exists()  # nothing ran, nothing written


def test_compare_runs_every_agent_on_the_same_episodes(tmp_path, capsys):
    args = [
        f"output_dir={tmp_path}",
        "agents=[expert,random]",
        "num_episodes=2",
        "workers=1",
        "env.image_size=32",
        "env.max_episode_steps=20",
        *FAST,
    ]
    assert run_from_cli("compare", args) == 0
    table = json.loads((tmp_path / "compare.json").read_text())
    assert list(table) == ["expert", "random"]
    for agent in table:
        metrics = json.loads((tmp_path / agent / "metrics.json").read_text())
        assert table[agent]["success"] == metrics["metrics"]["success"]
        ids = [r["episode_id"] for r in rows_of(tmp_path / agent)]
        assert ids == [r["episode_id"] for r in rows_of(tmp_path / "expert")]
    md = (tmp_path / "compare.md").read_text()
    assert "| expert" in md and "| random" in md and "| random" in capsys.readouterr().out


@pytest.mark.slow
def test_eval_killed_with_sigkill_and_run_again_equals_a_straight_run(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    common = ["agent=random", "num_episodes=6", "env.max_episode_steps=150"]
    args = ["--config-name", "config_debug", *common, *FAST, "eval.video_successes=0"]
    out = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    cmd = [sys.executable, "-m", "vla_gr.evaluate", *args, f"output_dir={out}"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rows_file = out / "episodes.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if rows_file.is_file() and len(rows_file.read_text().splitlines()) >= 2:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    finished = len(rows_file.read_text().splitlines())
    assert 2 <= finished < 6, "the kill should land mid-run"
    assert subprocess.run(cmd, env=env, capture_output=True).returncode == 0
    straight = evaluate(cfg_for(tmp_path / "straight", *common))
    resumed = json.loads((out / "metrics.json").read_text())
    assert without_timing(resumed) == without_timing(straight)
    assert no_latency(rows_of(out)) == no_latency(rows_of(tmp_path / "straight"))


class TwoPart(Constant):
    """A scripted agent that reports the time of its two parts, as a dual system would."""

    def act(self, obs) -> np.ndarray:
        self.last_timings = {"s1": 0.002, "s2": 0.010}  # seconds
        return self.action


def test_latency_is_reported_per_part_the_agent_names(tmp_path, monkeypatch):
    monkeypatch.setitem(AGENTS, "two_part", lambda cfg, env: TwoPart([0.5, 0.0, -1.0]))
    out = tmp_path / "parts"
    metrics = evaluate(cfg_for(out, "agent=two_part", "num_episodes=1", "env.max_episode_steps=5"))
    lat = metrics["latency_ms"]
    assert set(lat) == {"decision", "s1", "s2"}
    assert lat["s1"]["p50"] == pytest.approx(2.0) and lat["s2"]["p99"] == pytest.approx(10.0)
    assert lat["decision"]["calls"] == lat["s1"]["calls"] == 5
    assert "| s2" in (out / "report.md").read_text()


def test_true_mask_agent_reports_s1_and_s2_latency_on_its_schedule(tmp_path):
    # the planner's ceiling: the dual system with the true goal mask as S2's perception
    args = expand_aliases([f"output_dir={tmp_path}", *FAST, "agent=true_mask", "num_episodes=1"])
    cfg = load_config("config_cpu", [*args, "env.max_episode_steps=200"])[1]
    metrics = evaluate(cfg)
    assert metrics["metrics"]["success"] == 1.0  # val episode 0: the goal is close and seen
    lat = metrics["latency_ms"]
    steps = len(rows_of(tmp_path)[0]["actions"])
    assert lat["s1"]["calls"] == lat["decision"]["calls"] == steps
    assert lat["s2"]["calls"] == -(-steps // 3)  # a tick every 3 control steps, from step 0


class _BlindPerception:
    """Perceives a goal likelihood of zero everywhere (an instruction that names nothing it
    can ground)."""

    def reset(self) -> None:
        pass

    def read(self, instruction: str) -> None:
        return None  # it reads no request into fields: it acts on every one

    def perceive(self, obs) -> Percept:
        return Percept(np.zeros(obs["depth"].shape[:2], np.float32))  # (H, W)


class _BlindDualSystem(UntrainedDualSystemAgent):
    """The dual system on a blind perception: it only explores, and its goal confidence
    stays 0."""

    def __init__(self, cfg, env) -> None:
        super().__init__(GroundedDualSystem.from_model_config(_BlindPerception(), cfg.model))


register_agent("test_blind_dual_system")(_BlindDualSystem)


def test_an_agent_that_never_confirms_a_goal_is_flagged(tmp_path):
    def run(out, agent):
        args = [f"output_dir={out}", *FAST, f"agent={agent}", "num_episodes=2"]
        return evaluate(load_config("config_cpu", [*expand_aliases(args), *SHORT])[1])

    metrics = run(tmp_path, "test_blind_dual_system")
    assert [r["agent"]["goal_confidence"] for r in rows_of(tmp_path)] == [0.0, 0.0]
    assert metrics["low_goal_confidence"] == [0, 1]
    assert "Low goal confidence** in 2 episode(s)" in (tmp_path / "report.md").read_text()
    # an agent without a planner reports nothing to flag
    assert run(tmp_path / "expert", "expert")["low_goal_confidence"] == []


SHORT = ["env.max_episode_steps=20"]


class ReadsRequests(EvalAgent):
    """Reads each request as a fixed table says (keyed by the observed, folded instruction),
    declares ``not_understood`` on a request it did not understand, else stands still."""

    def __init__(self, table: dict[str, dict]) -> None:
        self.table = table
        self.said: str | None = None
        self.declared: str | None = None

    def reset(self, seed: int | None = None) -> None:
        self.said = self.declared = None

    def act(self, obs) -> np.ndarray:
        self.said = obs["instruction"]
        if not self.table[self.said]["understood"]:
            self.declared = "not_understood"
        return np.array([0.0, 0.0, -1.0], np.float32)

    @property
    def declared_outcome(self) -> str | None:
        return self.declared

    def reading(self) -> dict | None:
        return None if self.said is None else self.table[self.said]


def _reading(understood: bool, **fields) -> dict:
    named = {"category": None, "color": None, "room": None, "anchor": None, **fields}
    return {
        **named,
        "relation": "near" if named["anchor"] else None,
        "confidence": {},
        "unknown": [],
        "understood": understood,
        "reason": None,
    }


def test_a_request_not_understood_is_declared_counted_and_reported(tmp_path, monkeypatch, capsys):
    from vla_gr.envs.episodes import sample_episode, save_episodes
    from vla_gr.envs.instructions import parse_instruction

    a, b = sample_episode("val", 0), sample_episode("val", 1)
    fields = parse_instruction(a.instruction)
    piano = dataclasses.replace(
        a, instruction="I\u2019m looking for the piano \U0001f3b9", description=fields
    )
    file = save_episodes(tmp_path / "requests.jsonl", [piano, b, a])
    read_b = parse_instruction(b.instruction)
    wrong_a = dict(fields, color="purple" if fields["color"] != "purple" else "green")
    table = {
        "I'm looking for the piano": _reading(False),  # what the agent observes: folded
        b.instruction: _reading(
            True, **{k: read_b[k] for k in ("category", "color", "room")}, anchor=read_b["near"]
        ),
        a.instruction: _reading(
            True, **{k: wrong_a[k] for k in ("category", "color", "room")}, anchor=wrong_a["near"]
        ),
    }
    monkeypatch.setitem(AGENTS, "reads", lambda cfg, env: ReadsRequests(table))
    out = tmp_path / "reads"
    args = [
        f"output_dir={out}",
        *[x for x in FAST if "video_per_cause" not in x],
        "eval.video_per_cause=1",
        "agent=reads",
        f"episodes={file}",
        "env.max_episode_steps=5",
    ]
    assert run_from_cli("config_debug", args) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1] == "1 of 3 requests were not fully understood"

    rows = rows_of(out)
    declared, other = rows[0], rows[1]
    assert declared["declared"] == "not_understood" and declared["cause"] == "not_understood"
    assert declared["stopped"] is False and declared["metrics"]["success"] == 0.0
    assert declared["metrics"]["steps"] == len(declared["actions"]) == 1  # no wandering
    assert declared["reading"] == table["I'm looking for the piano"]
    assert declared["spec"]["description"] == fields
    assert declared["spec"]["instruction"] == piano.instruction  # the spec as written
    assert other["declared"] is None and other["metrics"]["steps"] == 5
    assert other["cause"] in ("timeout_goal_seen", "timeout_goal_never_seen")
    assert "description" not in other["spec"]

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["declared"] == {"not_understood": 1, "not_found": 0}
    assert metrics["not_understood"] == 1 and metrics["requests_read"] == 3
    assert metrics["failure_causes"]["not_understood"] == 1
    assert "reworded_instructions" not in metrics

    report = (out / "report.md").read_text()
    assert "- 1 of 3 requests were not fully understood." in report
    assert "not_understood 1, not_found 0" in report
    section = report.split("## Readings that differ from the episode's description")[1]
    section = section.split("\n## ")[0]
    assert "2 reading(s) differ" in section
    listed = [
        line for line in section.splitlines() if line.startswith("| ") and "episode" not in line
    ]
    assert [line.split("|")[1].strip() for line in listed] == ["0", "2"]  # b's reading agrees
    assert "(not understood)" in listed[0] and f"color={wrong_a['color']}" in listed[1]
    assert list(out.glob("episode_0000_not_understood*.mp4"))  # replayed with its declaration
