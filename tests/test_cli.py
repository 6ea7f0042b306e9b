"""The ``vla-gr`` command: help (each command's keys), ``--cfg job``, version, ``python -m``
entry points, the agent ``vla-gr eval`` runs when none is named, and the demo."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from vla_gr import __version__
from vla_gr.cli import COMMANDS, TOOLS, main
from vla_gr.configs.schema import SHIPPED_CHECKPOINT


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in ("collect", "demo", "train", "store", "read"):
        assert name in out
    assert set(COMMANDS) >= {"collect", "demo", "train"} and set(TOOLS) == {"read"}


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"vla-gr {__version__}"


def test_console_script_and_module_entry():
    # The console script installed beside this interpreter (PATH need not hold the venv).
    script = Path(sys.executable).with_name("vla-gr")
    out = subprocess.run([str(script), "--version"], capture_output=True, text=True, check=True)
    assert __version__ in out.stdout
    for module in ("vla_gr.data.collect", "vla_gr.demo"):
        res = subprocess.run(
            [sys.executable, "-m", module, "--help"], capture_output=True, text=True, check=True
        )
        assert "--config-name" in res.stdout


def _bad_episodes(tmp_path):
    good = {"episode_id": 0}
    path = tmp_path / "bad.jsonl"
    path.write_text("\n" + json.dumps(good) + "\n")  # line 2 lacks most fields
    return path


DEBUG = ["--config-name", "config_debug"]
USER_ERRORS = {
    "unknown key": (["train", *DEBUG, "model.nonexistent=1"], ["'model.nonexistent'", "head"]),
    "close key": (["train", *DEBUG, "model.head.objectiv=l1"], ["did you mean 'objective'"]),
    "root key": (["demo", *DEBUG, "nonexistent=1"], ["'nonexistent'", "training"]),
    "wrong type": (["train", *DEBUG, "training.steps=abc"], ["training.steps", "'abc'", "int"]),
    "negative lr": (["train", *DEBUG, "training.lr=-1"], ["training.lr=-1.0", "> 0"]),
    "unknown objective": (
        ["train", *DEBUG, "model.head.objective=foo"],
        ["model.head.objective='foo'", "flow_matching", "diffusion", "l1"],
    ),
    "unknown on_corrupt": (["train", *DEBUG, "training.on_corrupt=maybe"], ["error", "skip"]),
    "no equals": (["train", *DEBUG, "model.x"], ["'model.x'", "key=value"]),
    "unknown recipe": (["train", "--config-name", "nope"], ["'nope'", "config_debug"]),
    "missing episodes file": (
        ["eval", *DEBUG, "agent=expert", "episodes={tmp}/none.jsonl"],
        ["none.jsonl"],
    ),
    "bad episodes line": (
        ["eval", *DEBUG, "agent=expert", "episodes={bad}"],
        ["bad.jsonl:2", "missing"],
    ),
    "cfg package": (["eval", "--cfg", "job", "--package", "eval.nope"], ["eval.nope", "sections"]),
    "package alone": (["eval", "--package", "eval"], ["--cfg job"]),
    "not a store": (["store", "verify", "{tmp}/none.zarr"], ["none.zarr", "not an episode store"]),
}


@pytest.mark.parametrize("case", list(USER_ERRORS))
def test_user_errors_are_two_lines_naming_the_key(tmp_path, capsys, case):
    argv, needles = USER_ERRORS[case]
    bad = _bad_episodes(tmp_path)
    argv = [a.format(tmp=tmp_path, bad=bad) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert 1 <= len(err.strip().splitlines()) <= 2, err
    assert err.startswith(f"vla-gr {argv[0]}") and "Traceback" not in err
    for needle in needles:
        assert needle in err, (needle, err)


def test_bad_episodes_file_leaves_no_store(tmp_path, capsys):
    out = tmp_path / "c.zarr"
    argv = ["collect", *DEBUG, f"env.episodes={_bad_episodes(tmp_path)}", f"collect.output={out}"]
    assert main(argv) == 2
    assert "bad.jsonl:2" in capsys.readouterr().err and not out.exists()


def test_verbose_and_hydra_full_error_show_the_traceback(monkeypatch):
    from vla_gr.errors import ConfigError

    argv = ["train", *DEBUG, "training.steps=abc"]
    with pytest.raises(ConfigError, match="training.steps"):
        main([*argv, "--verbose"])
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(ConfigError):
        main(argv)


def test_console_script_error_output(tmp_path):
    script = Path(sys.executable).with_name("vla-gr")
    argv = [str(script), "demo", *DEBUG, "model.nonexistent=1"]  # demo: no torch import
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    res = subprocess.run(argv, capture_output=True, text=True, env=env)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 2
    assert "model.nonexistent" in res.stderr and "Traceback" not in res.stderr
    res = subprocess.run([*argv, "--verbose"], capture_output=True, text=True, env=env)
    assert res.returncode == 1 and "Traceback" in res.stderr and "ConfigError" in res.stderr
    module = [sys.executable, "-m", "vla_gr.demo", *DEBUG, "demo.num_episodes=abc"]
    res = subprocess.run(module, capture_output=True, text=True, env=env)
    assert res.returncode == 2 and res.stderr.startswith("python -m vla_gr.demo: error:")
    assert len(res.stderr.strip().splitlines()) == 1


def test_demo_runs_on_debug_config(tmp_path, capsys):
    out_dir = tmp_path / "demo"
    argv = ["demo", "--config-name", "config_debug", f"demo.output_dir={out_dir}"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "| name" in out and "| expert" in out and "report:" in out
    metrics = json.loads((out_dir / "metrics.json").read_text())
    assert metrics["agent"] == "expert" and metrics["metrics"]["episodes"] == 1
    assert (out_dir / "episodes.jsonl").read_text().count("\n") == 1
    assert (out_dir / "report.md").is_file()
    videos = sorted(out_dir.glob("*.mp4"))
    assert videos and f'<video src="{videos[0].name}"' in (out_dir / "report.html").read_text()
    # a second demo starts afresh instead of resuming the first one's rows
    assert main(argv) == 0
    assert json.loads((out_dir / "metrics.json").read_text())["timing"]["episodes_run"] == 1
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("x")
    assert (
        main(["demo", "--config-name", "config_debug", f"demo.output_dir={tmp_path / 'other'}"])
        == 2
    )
    assert (tmp_path / "other" / "keep.txt").exists()


def test_no_module_imports_the_cli():
    """The entry plumbing lives in vla_gr.configs.command: apps import it downward."""
    import vla_gr

    root = Path(vla_gr.__file__).parent
    upward = [
        str(p.relative_to(root))
        for p in root.rglob("*.py")
        if p.name != "cli.py" and "vla_gr.cli" in p.read_text(encoding="utf-8")
    ]
    assert upward == []


def _help(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize(
    "command, lines",
    [
        ("eval", ["num_episodes=null", "None: 10 of a split", "agent=null", "checkpoint=null"]),
        ("collect", ["collect.num_episodes=200", "episodes recorded", "expert.noise_std=0.15"]),
        ("demo", [f"demo.checkpoint={SHIPPED_CHECKPOINT}", "demo.num_episodes=20"]),
        ("train", ["training.steps=4000", "optimiser steps", "model.peft.method=lora"]),
    ],
)
def test_help_lists_the_commands_keys_with_defaults_and_meanings(capsys, command, lines):
    out = _help([command, "--help"], capsys)
    assert "--cfg" in out and "--config-name" in out
    keys = out[out.index("keys (") :]
    for needle in lines:
        assert needle in keys, (needle, keys)
    row = next(x for x in keys.splitlines() if x.split("=")[0].strip() == lines[0].split("=")[0])
    assert len(row.split()) > 1  # the key's meaning on its line


def test_every_key_a_help_lists_has_a_meaning():
    from omegaconf import OmegaConf

    from vla_gr.configs import load_config
    from vla_gr.configs.keys import COMMAND_SECTIONS, command_rows
    from vla_gr.configs.schema import VLAGRConfig

    cfg = OmegaConf.to_container(load_config("config_cpu")[0], resolve=True)
    assert set(COMMAND_SECTIONS) == set(COMMANDS)
    for command in COMMANDS:
        rows = command_rows(command, cfg, VLAGRConfig)
        assert len(rows) > 10
        missing = [key for key, _, meaning in rows if not meaning]
        assert missing == [], (command, missing)


def test_help_shows_the_defaults_of_the_recipe_named_before_it(capsys):
    out = _help(["demo", "--config-name", "config_debug", "--help"], capsys)
    assert "defaults of --config-name config_debug" in out and "demo.agent=expert" in out
    out = _help(["demo", "--help"], capsys)
    assert "defaults of --config-name config_cpu" in out and "demo.agent=checkpoint" in out


def test_cfg_job_prints_the_resolved_config_and_runs_nothing(tmp_path, capsys):
    out_dir = tmp_path / "never"
    argv = ["collect", "--cfg", "job", "collect.split=val", f"collect.output={out_dir}/s.zarr"]
    assert main(argv) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["collect"]["split"] == "val" and printed["collect"]["num_episodes"] == 200
    assert printed["model"]["image_size"] == 64  # an interpolation (${env.image_size}), resolved
    assert not out_dir.exists()
    assert main(["collect", "--cfg", "job", "-p", "collect.output"]) == 0
    assert capsys.readouterr().out.strip() == "collect.output: data/expert_train.zarr"


def test_cfg_job_of_eval_shows_the_agent_it_would_run(capsys):
    assert main(["eval", "--cfg", "job", "--package", "eval", "num_episodes=3"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["agent"] == "checkpoint" and printed["checkpoint"] == SHIPPED_CHECKPOINT
    assert printed["num_episodes"] == 3
    assert main(["eval", "--cfg", "job", "--package", "eval", "agent=expert"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["agent"] == "expert" and printed["checkpoint"] is None


def test_module_entry_takes_help_and_cfg():
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    cmd = [sys.executable, "-m", "vla_gr.evaluate", "--cfg", "job", "-p", "eval.checkpoint"]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    assert res.stdout.strip() == f"eval.checkpoint: {SHIPPED_CHECKPOINT}"
    cmd = [sys.executable, "-m", "vla_gr.data.collect", "--help"]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    assert "collect.workers=2" in res.stdout


@pytest.mark.parametrize(
    "config_name, overrides, agent, checkpoint",
    [
        ("config_cpu", [], "checkpoint", SHIPPED_CHECKPOINT),  # nothing named: the shipped agent
        ("config_debug", ["num_episodes=2"], "checkpoint", SHIPPED_CHECKPOINT),
        ("config_cpu", ["agent=expert"], "expert", None),  # asked for
        ("config_cpu", ["checkpoint=runs/x"], None, "runs/x"),  # the checkpoint agent on it
        ("config_cpu", ["eval.agent=random"], "random", None),
        ("compare", [], None, None),  # the recipe names its agents (expert, random)
    ],
)
def test_eval_names_its_agent_and_defaults_to_the_shipped_checkpoint(
    config_name, overrides, agent, checkpoint
):
    from vla_gr.evaluate import compose_from_cli
    from vla_gr.evaluation.harness import default_agent

    resolved, cfg = compose_from_cli(config_name, overrides)
    assert (cfg.eval.agent, cfg.eval.checkpoint) == (agent, checkpoint)
    assert (resolved.eval.agent, resolved.eval.checkpoint) == (agent, checkpoint)
    if not cfg.eval.agents:
        assert default_agent(cfg) != "expert" or "agent=expert" in overrides


def test_bare_eval_says_it_runs_the_shipped_agent_in_its_first_line(monkeypatch, capsys):
    import vla_gr.evaluate as app
    from vla_gr.errors import UserError

    ran = []

    def stop(cfg):  # what would run, without running it
        ran.append(cfg.eval)
        raise UserError("stopped before any episode")

    monkeypatch.setattr(app, "evaluate", stop)
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # the repository, which ships it
    assert main(["eval", "num_episodes=2"]) == 2
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith(f"agent: the shipped checkpoint {SHIPPED_CHECKPOINT}")
    assert (ran[0].agent, ran[0].checkpoint) == ("checkpoint", SHIPPED_CHECKPOINT)
    assert main(["eval", "agent=expert", "num_episodes=2"]) == 2
    assert "shipped" not in capsys.readouterr().out and ran[1].agent == "expert"


def test_bare_eval_away_from_the_shipped_checkpoint_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "num_episodes=1"]) == 2
    captured = capsys.readouterr()
    assert captured.out.startswith("agent: the shipped checkpoint")
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and SHIPPED_CHECKPOINT in err and "checkpoint=PATH" in err
