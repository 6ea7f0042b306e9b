"""The ``vla-gr`` command: help, version, ``python -m`` entry points, and the demo."""

import json
import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import pytest

from vla_gr import __version__
from vla_gr.cli import COMMANDS, TOOLS, main


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
    "missing episodes file": (["eval", *DEBUG, "episodes={tmp}/none.jsonl"], ["none.jsonl"]),
    "bad episodes line": (["eval", *DEBUG, "episodes={bad}"], ["bad.jsonl:2", "missing"]),
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
    gifs = sorted(out_dir.glob("*.gif"))
    assert gifs and iio.imread(gifs[0], index=None).ndim == 4  # (N, H, W, 3) frames
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
