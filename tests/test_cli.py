"""The ``vla-gr`` command: help, version, ``python -m`` entry points, and the demo."""

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import pytest

from vla_gr import __version__
from vla_gr.cli import COMMANDS, main


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in ("collect", "demo", "train"):
        assert name in out
    assert set(COMMANDS) >= {"collect", "demo", "train"}


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


def test_unknown_config_key_is_hydra_error(tmp_path):
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException):
        main(["demo", "--config-name", "config_debug", "demo.no_such_key=1"])


def test_demo_runs_on_debug_config(tmp_path, capsys):
    out_dir = tmp_path / "demo"
    assert main(["demo", "--config-name", "config_debug", f"demo.output_dir={out_dir}"]) == 0
    table = capsys.readouterr().out
    assert "| name" in table and "expert (mean of 1)" in table and "spl" in table
    metrics = json.loads((out_dir / "metrics.json").read_text())
    assert metrics["aggregate"]["episodes"] == 1
    ep = metrics["episodes"][0]
    assert ep["metrics"]["success"] in (0.0, 1.0)
    gif = iio.imread(out_dir / "episode_000.gif", index=None)  # (N, H, 3H, 3)
    assert gif.shape[1] == 64 and gif.shape[2] == 3 * 64
    assert 2 <= gif.shape[0] <= ep["gif_frames"]  # identical frames may merge
    png = iio.imread(out_dir / "episode_000_topdown.png")
    assert png.shape[0] == 128 and png.ndim == 3
    assert (out_dir / "episodes.jsonl").read_text().count("\n") == 1
