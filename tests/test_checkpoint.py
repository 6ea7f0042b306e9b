"""Checkpoints: round trips, refusal of corrupt / mismatched ones, survival of SIGKILL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import torch

from tests.helpers import tiny_policy
from vla_gr import checkpoint as ckpt
from vla_gr.policy import VLAGRPolicy
from vla_gr.training.optim import build_optimizer


def _save(root, step, value=1.0, links=("latest",)):
    return ckpt.save_checkpoint(
        root,
        step,
        {"w": torch.full((3, 2), value)},
        {"step": step},
        f"step: {step}\n",
        {"optim.0.exp_avg": torch.zeros(2)},
        links,
    )


def test_save_read_round_trip_and_links(tmp_path):
    _save(tmp_path, 1, 1.0, links=("latest", "best"))
    _save(tmp_path, 2, 2.0)
    latest = ckpt.read_checkpoint(tmp_path / "latest")
    assert latest.state == {"step": 2} and latest.config_yaml == "step: 2\n"
    assert torch.equal(latest.model["w"], torch.full((3, 2), 2.0))
    assert torch.equal(latest.group("optim")["0.exp_avg"], torch.zeros(2))
    assert ckpt.read_checkpoint(tmp_path / "best").state["step"] == 1
    _save(tmp_path, 3, 3.0)
    ckpt.prune_checkpoints(tmp_path, keep=1)
    left = sorted(p.name for p in tmp_path.glob("step_*"))
    assert left == ["step_00000001", "step_00000003"]  # step 1 survives: `best` points at it


def test_every_checkpoint_file_gets_the_permissions_of_a_plain_new_file(tmp_path):
    old = os.umask(0o022)
    try:
        folder = _save(tmp_path, 1)
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in folder.iterdir()}
    assert set(modes.values()) == {0o644}, modes  # safetensors alone would write 0600


def test_optimizer_state_round_trip_without_pickle():
    model = tiny_policy(0)
    opt = build_optimizer(model, lr=1e-3, weight_decay=0.1)
    for p in model.parameters():
        p.grad = torch.randn_like(p)
    opt.step()
    tensors, meta = ckpt.flatten_optimizer_state(opt.state_dict())
    assert all(isinstance(v, torch.Tensor) for v in tensors.values())
    meta = json.loads(json.dumps(meta))  # must survive JSON
    fresh = build_optimizer(tiny_policy(0), lr=5.0, weight_decay=0.0)
    fresh.load_state_dict(ckpt.unflatten_optimizer_state(tensors, meta))
    a, b = opt.state_dict(), fresh.state_dict()
    assert a["param_groups"] == b["param_groups"]
    for idx, entry in a["state"].items():
        for key, value in entry.items():
            torch.testing.assert_close(b["state"][idx][key], value, rtol=0, atol=0)


def test_corrupt_or_incomplete_checkpoints_are_refused(tmp_path):
    path = _save(tmp_path, 1)
    data = bytearray((path / "model.safetensors").read_bytes())
    data[-1] ^= 0xFF
    (path / "model.safetensors").write_bytes(bytes(data))
    with pytest.raises(ckpt.CheckpointError, match="SHA-256"):
        ckpt.read_checkpoint(path)
    (path / "model.safetensors").write_bytes(bytes(data[:-4]))
    with pytest.raises(ckpt.CheckpointError, match="truncated"):
        ckpt.read_checkpoint(path)
    (path / "manifest.json").unlink()
    with pytest.raises(ckpt.CheckpointError, match="incomplete"):
        ckpt.read_checkpoint(path)
    with pytest.raises(ckpt.CheckpointError, match="does not exist"):
        ckpt.read_checkpoint(tmp_path / "nope")


def test_mismatched_weights_are_refused_with_names():
    model = tiny_policy(0)
    state = dict(model.state_dict())
    state["vision.pos"] = torch.zeros(7, 7)
    del state["pose.net.0.bias"]
    state["extra.weight"] = torch.zeros(1)
    with pytest.raises(ckpt.CheckpointError) as err:
        ckpt.load_model_state(model, state, "ckpt-x")
    msg = str(err.value)
    assert "ckpt-x" in msg and "vision.pos" in msg and "pose.net.0.bias" in msg
    assert "extra.weight" in msg


def test_a_warm_start_may_lack_entries_but_not_carry_extra_or_misshaped_ones():
    model = tiny_policy(0)
    fresh = {k: v.clone() for k, v in model.state_dict().items()}
    source = tiny_policy(1).state_dict()
    partial = {k: v for k, v in source.items() if k != "pose.net.0.bias"}
    with pytest.raises(ckpt.CheckpointError, match="1 missing"):
        ckpt.load_model_state(model, partial, "ckpt-x")
    assert ckpt.load_model_state(model, partial, "ckpt-x", allow_missing=True) == [
        "pose.net.0.bias"
    ]
    loaded = model.state_dict()
    torch.testing.assert_close(loaded["pose.net.0.bias"], fresh["pose.net.0.bias"])
    for key, value in partial.items():
        torch.testing.assert_close(loaded[key], value)
    extra, misshaped = {"extra.weight": torch.zeros(1)}, {"vision.pos": torch.zeros(7)}
    for bad in ({**partial, **extra}, {**partial, **misshaped}):
        with pytest.raises(ckpt.CheckpointError):
            ckpt.load_model_state(model, bad, "ckpt-x", allow_missing=True)


def test_config_differences_names_keys():
    old = {"model": {"dim": 32, "peft": {"enabled": False}}, "seed": 0}
    new = {"model": {"dim": 64, "peft": {"enabled": True}}, "seed": 0}
    assert ckpt.config_differences(old, new) == [
        "model.dim: 32 -> 64",
        "model.peft.enabled: False -> True",
    ]


_CHILD = textwrap.dedent(
    """
    import sys, time, torch
    from vla_gr import checkpoint as ckpt
    root, mode = sys.argv[1], sys.argv[2]
    def save(step):
        w = torch.full((256, 1024), float(step))  # 1 MiB per file
        ckpt.save_checkpoint(root, step, {"w": w}, {"step": step}, "x: 1\\n", {"t": w}, ["latest"])
    save(1)
    if mode == "pause":  # freeze for good right after the first file of step 2 is written
        original = ckpt._save_tensors
        def paused(path, tensors):
            original(path, tensors)
            print("WRITING", flush=True)
            time.sleep(600)
        ckpt._save_tensors = paused
        save(2)
    else:  # save as fast as possible until killed
        print("WRITING", flush=True)
        step = 2
        while True:
            save(step)
            ckpt.prune_checkpoints(root, keep=2)
            step += 1
    """
)


@pytest.mark.parametrize("mode", ["pause", "loop"])
def test_sigkill_during_checkpoint_write_keeps_latest_loadable(tmp_path, mode):
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(tmp_path), mode], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline().strip() == "WRITING"
        if mode == "loop":
            time.sleep(0.3)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    latest = ckpt.read_checkpoint(tmp_path / "latest")  # verifies every checksum
    step = latest.state["step"]
    assert torch.equal(latest.model["w"], torch.full((256, 1024), float(step)))
    if mode == "pause":
        assert step == 1
        assert list(tmp_path.glob(".tmp-step_00000002-*"))  # the half-written folder
    _save(tmp_path, 1000)
    ckpt.prune_checkpoints(tmp_path, keep=2)
    assert not list(tmp_path.glob(".tmp-*"))  # leftovers of the killed writer removed
    assert ckpt.read_checkpoint(tmp_path / "latest").state["step"] == 1000


def test_a_run_folder_instead_of_a_checkpoint_names_the_checkpoints_it_holds(tmp_path):
    run = tmp_path / "stage" / "run"
    _save(run / "checkpoints", 1)
    _save(run / "checkpoints", 2, links=("latest", "best"))
    best, latest = run / "checkpoints" / "best", run / "checkpoints" / "latest"
    held = "checkpoints/best, checkpoints/latest, checkpoints/step_00000002, checkpoints/step_0000"
    for given, kind, names in (
        (run, "run folder", held),
        (run / "checkpoints", "checkpoints folder", held.replace("checkpoints/", "")),
        (tmp_path / "stage", "folder", held.replace("checkpoints/", "run/checkpoints/")),
    ):
        with pytest.raises(ckpt.CheckpointError) as err:
            ckpt.read_checkpoint(given)
        message = str(err.value)
        assert message.startswith(f"{given} is a {kind}, not a checkpoint; did you mean {best}?")
        assert f"It holds {names}" in message and "manifest" not in message, message
    with pytest.raises(ckpt.CheckpointError, match=f"did you mean {best}"):
        VLAGRPolicy.from_pretrained(run)  # the agent's checkpoint: best
    with pytest.raises(ckpt.CheckpointError, match=f"did you mean {latest}"):
        ckpt.read_checkpoint(run, prefer="latest")  # resuming: latest
    for link in ("best", "latest"):
        (run / "checkpoints" / link).unlink()  # step folders only: the newest is suggested
    with pytest.raises(ckpt.CheckpointError, match=f"did you mean {run}/checkpoints/step_0+2\\?"):
        ckpt.read_checkpoint(run)


def test_a_folder_without_checkpoints_says_what_a_checkpoint_is(tmp_path):
    with pytest.raises(ckpt.CheckpointError) as err:
        ckpt.read_checkpoint(tmp_path)
    assert "is not a checkpoint" in str(err.value) and "incomplete" not in str(err.value)
    assert "<run>/checkpoints/best" in str(err.value)
    path = _save(tmp_path / "checkpoints", 1)
    (path / "manifest.json").unlink()  # a checkpoint's files without their manifest
    with pytest.raises(ckpt.CheckpointError, match="has no manifest.json: incomplete write"):
        ckpt.read_checkpoint(path)


@pytest.mark.parametrize(
    "fname",
    ["trainer_state.json", "config.yaml", "model.safetensors", "training_state.safetensors"],
)
def test_garbage_that_matches_the_manifest_is_refused_naming_the_file(tmp_path, fname):
    """A manifest edited to match a garbage file passes the checksums; parsing still names it."""
    path = _save(tmp_path, 1)
    (path / fname).write_bytes(b"{not: [valid\x00\xff")
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["files"][fname] = {
        "sha256": ckpt.sha256_file(path / fname),
        "bytes": (path / fname).stat().st_size,
    }
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ckpt.CheckpointError, match=f"{path}.*{fname}"):
        ckpt.read_checkpoint(path)
