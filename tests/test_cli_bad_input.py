"""Bad input a new user gives ``vla-gr``: an episodes file line the world cannot run, a range
past the file's end, a run folder where a checkpoint goes. Each ends before any work in one or
two lines on stderr naming the file and line, the key or the folder to use, with exit code 2."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from vla_gr import checkpoint as ckpt
from vla_gr.cli import main
from vla_gr.envs.episodes import DESCRIPTION_FIELDS, sample_episode, save_episodes

DEBUG = ["--config-name", "config_debug"]


def _record(**changes) -> dict:
    """Episode 0 of ``val`` as a file's record, with ``changes``, declaring its goal (a
    hand-written request), so that its instruction is not what refuses it."""
    spec = sample_episode("val", 0)
    record = spec.to_dict()
    record["description"] = dict.fromkeys(DESCRIPTION_FIELDS) | {"category": spec.goal_category}
    return record | changes


def _other_category() -> str:
    return "sofa" if sample_episode("val", 0).goal_category != "sofa" else "bed"


#: name -> (the line's record, or its bytes; what the error names besides the file and line)
BAD_LINES = {
    "goal not in the house": (lambda: _record(goal_instance_id=999), "goal object 999 is missing"),
    "goal of another category": (
        lambda: _record(goal_category=_other_category()),
        "not a {other}",
    ),
    "start outside the map": (lambda: _record(start_x=1e9), "is outside the map"),
    "split not a split": (lambda: _record(split="vall"), "split='vall'"),
    "no such house": (lambda: _record(num_rooms=99), "num_rooms=99"),
    "instruction not text": (lambda: _record(instruction=5), "'instruction': 'int'"),
    "instruction too long": (
        lambda: _record(instruction="find the chair " + "please " * 40),
        "limit of 256",
    ),
    "not UTF-8": (lambda: b"\xff\xfe{}\n", "utf-8"),
}


def _write_line(path: Path, line) -> Path:
    data = line if isinstance(line, bytes) else (json.dumps(line) + "\n").encode()
    path.write_bytes(data)
    return path


def _one_or_two_lines(err: str, prog: str) -> str:
    err = err.strip()
    assert 1 <= len(err.splitlines()) <= 2, err
    assert err.startswith(f"vla-gr {prog}: error:") and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("command", ["eval", "collect"])
@pytest.mark.parametrize("case", list(BAD_LINES))
def test_a_line_the_world_cannot_run_is_named_by_file_and_line(tmp_path, capsys, case, command):
    make, needle = BAD_LINES[case]
    good = save_episodes(tmp_path / "eps.jsonl", [sample_episode("val", 0)]).read_bytes()
    path = _write_line(tmp_path / "eps.jsonl", make())
    path.write_bytes(good + path.read_bytes())  # the bad record is line 2
    out = tmp_path / "out"
    argv = {
        "eval": ["eval", *DEBUG, "agent=expert", f"episodes={path}", f"output_dir={out}"],
        "collect": ["collect", *DEBUG, f"env.episodes={path}", f"collect.output={out}"],
    }[command]
    assert main(argv) == 2
    err = _one_or_two_lines(capsys.readouterr().err, command)
    assert f"{path}:2: " in err and needle.format(other=_other_category()) in err, err
    assert not out.exists()  # refused before any episode: nothing written


def test_a_non_ascii_instruction_is_read_folded_as_the_world_shows_it(tmp_path):
    from vla_gr.envs.episodes import load_episodes

    spec = sample_episode("val", 0)
    accented = spec.instruction.replace("e", "\u00e9").replace("a", "\u00e1") + " \u2713"
    specs = [dataclasses.replace(spec, instruction=accented)]
    assert load_episodes(save_episodes(tmp_path / "eps.jsonl", specs)) == specs


def test_collect_past_the_end_of_its_episodes_file_names_the_keys(tmp_path, capsys):
    path = save_episodes(tmp_path / "eps.jsonl", [sample_episode("val", 0)])
    out = tmp_path / "c.zarr"
    argv = ["collect", *DEBUG, f"env.episodes={path}", "collect.num_episodes=3"]
    assert main([*argv, f"collect.output={out}"]) == 2
    err = _one_or_two_lines(capsys.readouterr().err, "collect")
    assert "collect.num_episodes=3" in err and f"the 1 episodes of episodes file {path}" in err
    assert not out.exists()


@pytest.mark.parametrize("command", ["eval", "read"])
def test_a_run_folder_as_the_checkpoint_names_its_checkpoints(tmp_path, capsys, command):
    run = tmp_path / "run"
    for step, links in ((1, ()), (2, ("latest", "best"))):
        ckpt.save_checkpoint(
            run / "checkpoints", step, {"w": torch.zeros(1)}, {"step": step}, "a: 1\n", None, links
        )
    argv = {
        "eval": ["eval", *DEBUG, f"checkpoint={run}", f"output_dir={tmp_path / 'out'}"],
        "read": ["read", "find the chair", f"checkpoint={run}"],
    }[command]
    assert main(argv) == 2
    err = _one_or_two_lines(capsys.readouterr().err, command)
    assert f"{run} is a run folder, not a checkpoint; did you mean {run}/checkpoints/best?" in err
    assert "checkpoints/latest, checkpoints/step_00000002, checkpoints/step_00000001" in err


def test_eval_given_the_episodes_file_as_env_episodes_says_which_key_it_reads(tmp_path, capsys):
    path = save_episodes(tmp_path / "eps.jsonl", [sample_episode("val", 0)])
    out = tmp_path / "out"
    argv = ["eval", *DEBUG, "agent=expert", f"env.episodes={path}", f"output_dir={out}"]
    assert main(argv) == 2  # not the split's episodes in its place
    err = _one_or_two_lines(capsys.readouterr().err, "eval")
    assert f"env.episodes={path}" in err and f"pass episodes={path}" in err
    assert not out.exists()
