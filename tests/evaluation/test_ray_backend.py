"""``backend=ray``: episodes as Ray actors on a cluster (a head and one more node, started here),
the checkpoint and episode specs through the object store, rows written here in episode order;
a driver killed mid-run resumes and its file equals a local run's; collect writes the same
store; a bad backend, or Ray missing, is one line."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from tests.evaluation.test_variants import write_checkpoint
from vla_gr.cli import main as cli_main
from vla_gr.configs import load_config
from vla_gr.evaluate import evaluate, expand_aliases
from vla_gr.evaluation.summary import without_timing

FAST = ["eval.progress=false", "eval.video_successes=0", "eval.video_per_cause=0", "seed=3"]
NUM_EPISODES = 8


def rows_of(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "episodes.jsonl").read_text().splitlines()]


def no_latency(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "latency_ms"} for r in rows]


@pytest.fixture(scope="module")
def agent(tmp_path_factory) -> tuple[str, str]:
    """(checkpoint, episodes file): a tiny untrained dual system and val episodes 0-7."""
    from vla_gr.envs.episodes import sample_episode, save_episodes

    tmp = tmp_path_factory.mktemp("ray_agent")
    checkpoint = write_checkpoint(tmp / "ckpt", "model.agent=dual_system")
    specs = [sample_episode("val", k) for k in range(NUM_EPISODES)]
    return checkpoint, str(save_episodes(tmp / "episodes.jsonl", specs))


def eval_args(agent: tuple[str, str]) -> list[str]:
    checkpoint, episodes = agent
    return [f"checkpoint={checkpoint}", f"episodes={episodes}", "env.max_episode_steps=150"]


@pytest.fixture(scope="module")
def cluster():
    """A Ray cluster of two nodes (processes on this machine), one CPU each; stopped after."""
    cluster_utils = pytest.importorskip("ray.cluster_utils")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths live there
    # Ray records the head's address in its default temp folder whatever temp_dir says, and
    # does not make that folder: on a machine that never ran Ray it must exist first
    from ray._private.utils import get_ray_address_file

    os.makedirs(os.path.dirname(get_ray_address_file(None)), exist_ok=True)
    node = {"num_cpus": 1, "object_store_memory": 80 * 2**20, "include_dashboard": False}
    node["dashboard_agent_listen_port"] = None  # a free port, not Ray's fixed default
    cluster = cluster_utils.Cluster(initialize_head=True, head_node_args={**node, "temp_dir": temp})
    try:
        cluster.add_node(**node)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        cluster.shutdown()
        shutil.rmtree(temp, ignore_errors=True)


def test_a_killed_ray_run_resumes_and_equals_a_local_run(tmp_path, agent, cluster):
    """Two Ray workers on two nodes; the driver is SIGKILLed after some rows, run again, and
    its episodes.jsonl and metrics.json equal an uninterrupted local run's."""
    out = tmp_path / "ray"
    args = [*eval_args(agent), *FAST, "workers=2", "backend=ray"]
    args += [f"eval.ray_address={cluster.address}", f"output_dir={out}"]
    cmd = [sys.executable, "-m", "vla_gr.evaluate", "--config-name", "config_debug", *args]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    log = (tmp_path / "driver.log").open("w")
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    rows_file = out / "episodes.jsonl"
    deadline = time.monotonic() + 300  # a loaded machine starts Ray workers slowly
    while time.monotonic() < deadline and proc.poll() is None:
        if rows_file.is_file() and len(rows_file.read_text().splitlines()) >= 3:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    finished = len(rows_file.read_text().splitlines())
    assert 3 <= finished < NUM_EPISODES, (tmp_path / "driver.log").read_text()[-2000:]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]

    local = tmp_path / "local"
    straight = evaluate(load_config("config_debug", expand_aliases([
        *eval_args(agent), *FAST, f"output_dir={local}"]))[1])  # fmt: skip
    resumed = json.loads((out / "metrics.json").read_text())
    assert resumed["timing"]["backend"] == "ray" and resumed["timing"]["episodes_run"] < 8
    assert without_timing(resumed) == without_timing(straight)
    rows = rows_of(out)
    assert [r["episode_index"] for r in rows] == list(range(NUM_EPISODES))
    assert no_latency(rows) == no_latency(rows_of(local))


def test_ray_collect_writes_the_local_store(tmp_path, cluster):
    from vla_gr.data.store import EpisodeStore

    def collect(path: Path, *extra: str) -> EpisodeStore:
        args = ["collect", "--config-name", "config_debug", f"collect.output={path}"]
        args += ["collect.split=val", "collect.num_episodes=2", "env.max_episode_steps=60"]
        args += ["expert.noise_std=0.3", "expert.noise_prob=0.1", *extra]
        assert cli_main(args) == 0
        return EpisodeStore.open(path)

    address = f"collect.ray_address={cluster.address}"
    a = collect(tmp_path / "ray.zarr", "collect.backend=ray", "collect.workers=2", address)
    b = collect(tmp_path / "local.zarr")
    assert a.num_episodes == b.num_episodes == 2
    np.testing.assert_array_equal(a.episode_ends, b.episode_ends)
    for key in ("rgb", "depth", "pose", "action", "goal_mask", "distractor_mask"):
        np.testing.assert_array_equal(a.data_array(key)[:], b.data_array(key)[:], err_msg=key)
    assert [a.spec(e) for e in range(2)] == [b.spec(e) for e in range(2)]
    assert [a.metrics(e) for e in range(2)] == [b.metrics(e) for e in range(2)]


def test_the_checkpoint_travels_as_bytes_and_is_checked_on_the_worker(tmp_path, agent):
    """A worker loads the checkpoint from the bytes it was sent (not from the driver's path),
    runs the same rows, removes its copy at the end, and refuses a corrupted file."""
    from vla_gr.data.collect import env_kwargs_from_config
    from vla_gr.evaluation import ray_rows
    from vla_gr.evaluation.runner import _init_worker, _work

    checkpoint, _ = agent
    cfg = load_config("config_debug", expand_aliases([
        f"checkpoint={checkpoint}", "env.max_episode_steps=20", *FAST]))[1]  # fmt: skip
    env_kwargs = env_kwargs_from_config(cfg, "val")
    files = ray_rows.checkpoint_files(checkpoint)
    assert set(files) == {"manifest.json", "model.safetensors", "config.yaml",
                          "trainer_state.json"}  # fmt: skip
    elsewhere = dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, checkpoint="/nowhere"))
    ray_rows._init_remote(files, elsewhere, "checkpoint", env_kwargs, (0,))
    copy = ray_rows._LOCAL["folder"]
    remote = _work(0)
    ray_rows._close_remote()
    assert not copy.exists()
    _init_worker(cfg, "checkpoint", env_kwargs, (0,))
    local = _work(0)
    ray_rows._close_remote()
    assert no_latency([remote]) == no_latency([local])

    flipped = dict(files, **{"model.safetensors": files["model.safetensors"][:-1] + b"\0"})
    with pytest.raises(ValueError, match="model.safetensors fails its SHA-256 check"):
        ray_rows._init_remote(flipped, elsewhere, "checkpoint", env_kwargs, (0,))
    assert "folder" not in ray_rows._LOCAL  # the refused copy is removed too
    with pytest.raises(ValueError, match="not a plain file name"):
        ray_rows.write_checkpoint_files({"../x": b""}, tmp_path)


@pytest.mark.parametrize("command", ["eval", "collect"])
def test_a_bad_backend_or_missing_ray_is_one_line(tmp_path, capsys, monkeypatch, command):
    import importlib.util

    key = "eval.backend" if command == "eval" else "collect.backend"
    out = f"output_dir={tmp_path / 'out'}" if command == "eval" else f"collect.output={tmp_path}/x"
    argv = [command, "--config-name", "config_debug", "agent=random", out, f"{key}=nope"]
    if command == "collect":
        argv.remove("agent=random")
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert f"{key}='nope' is not valid; choose one of ['local', 'ray']" in err, err
    assert len(err.splitlines()) == 1

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "ray" else find_spec(name, *a)
    )
    assert cli_main([*argv[:-1], f"{key}=ray"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{key}=ray needs Ray, which is not installed: pip install 'vla-gr[ray]'" in err, err
    assert len(err.splitlines()) == 1
    assert not list(tmp_path.iterdir())  # nothing ran, nothing written


def test_an_address_where_no_cluster_answers_is_one_line(tmp_path, capsys):
    import socket

    pytest.importorskip("ray")
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    argv = ["eval", "--config-name", "config_debug", "agent=random", *FAST, "backend=ray"]
    argv += [f"eval.ray_address=127.0.0.1:{port}", f"output_dir={tmp_path}"]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert f"eval.ray_address=127.0.0.1:{port}: no Ray cluster answers there" in err, err
    assert len(err.splitlines()) == 1


def test_no_more_workers_than_the_cluster_holds_at_once(caplog):
    """An actor the cluster cannot place would hold up the episodes handed to it."""
    from vla_gr.data.ray_workers import _workers_that_fit
    from vla_gr.errors import ConfigError

    assert _workers_that_fit({"CPU": 4.0}, 2, 0.0, "eval") == 2
    assert _workers_that_fit({"CPU": 4.0, "GPU": 1.0}, 3, 1.0, "eval") == 1
    assert "holds 1 workers at once, not 3" in caplog.text
    with pytest.raises(ConfigError, match="eval.backend=ray: the Ray cluster has 2 CPU, 0 GPU"):
        _workers_that_fit({"CPU": 2.0}, 2, 1.0, "eval")
