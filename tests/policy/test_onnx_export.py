"""The shipped agent's perception under ONNX Runtime: the same outputs and decisions as PyTorch
on real frames and in closed loop; the export is tied to its weights in the manifest."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import save_file

from vla_gr.agent.observations import env_obs_to_frame
from vla_gr.agent.perception.engine import OnnxNetwork
from vla_gr.checkpoint import MODEL_FILE, CheckpointError, add_files, read_checkpoint
from vla_gr.data.collect import make_env
from vla_gr.policy import load_policy
from vla_gr.policy.onnx_export import RECORD, export_onnx, tick_observations

pytest.importorskip("onnx")

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"
TORCH = ["perception.engine=torch"]


@pytest.fixture(scope="module")
def agents():
    """The shipped agent as shipped (ONNX Runtime) and with PyTorch running its networks."""
    return load_policy(SHIPPED), load_policy(SHIPPED, overrides=TORCH)


@pytest.fixture(scope="module")
def ticks(agents):
    """Observations of the shipped agent's S2 ticks: its first 15 steps of val 0, 3 and 7."""
    return tick_observations(agents[0], (0, 3, 7), 15)


def _copy(tmp_path: Path) -> Path:
    dst = tmp_path / "agent"
    shutil.copytree(SHIPPED, dst)
    return dst


def test_the_shipped_agent_runs_its_checks_with_onnxruntime(agents):
    onnx, reference = agents
    assert onnx.config.perception.engine == "onnxruntime"
    assert set(onnx.perception.networks) == {"goal_head", "room_type", "object_category"}
    assert all(isinstance(n, OnnxNetwork) for n in onnx.perception.networks.values())
    assert reference.perception.networks == {}


def test_exported_networks_give_pytorchs_logits_on_real_frames(agents, ticks):
    onnx, _ = agents
    said = ["find the red chair near the table"]
    worst = {}
    for obs in ticks:
        frame = env_obs_to_frame({**obs, "instruction": said[0]})
        rgb, depth = frame["rgb"], frame["depth"]
        flipped = torch.cat([rgb, rgb.flip(-1)]), torch.cat([depth, depth.flip(-1)])  # as S2
        for name, module in onnx.perception_networks().items():
            extra = (said * 2,) if name == "goal_head" else ()
            inputs = module.network_inputs(*flipped, *extra)
            with torch.no_grad():
                expected = module.network(*inputs)
            got = onnx.perception.networks[name](*inputs)
            for key, value in expected.items():
                torch.testing.assert_close(got[key], value, atol=1e-4, rtol=1e-4)
                error = float((got[key] - value).abs().max())
                worst[f"{name}.{key}"] = max(worst.get(f"{name}.{key}", 0.0), error)
                if value.dim() == 4:  # the segmenter's classes: the same argmax
                    assert torch.equal(got[key].argmax(1), value.argmax(1))
                if name == "room_type":
                    assert torch.equal(got[key].argmax(-1), value.argmax(-1))
    assert len(worst) == 4 and max(worst.values()) < 5e-4, worst  # measured: 8e-5 at most


def test_percepts_and_their_decisions_are_pytorchs(agents, ticks):
    onnx, reference = agents
    threshold = onnx.config.navigator.confirmation.pixel_threshold
    requests = ["find the chair near the table", "the bed in the bedroom"]  # anchor, room check
    for said in requests:
        onnx.perception.reset()
        reference.perception.reset()
        for obs in ticks:
            a = onnx.perception.perceive({**obs, "instruction": said})
            b = reference.perception.perceive({**obs, "instruction": said})
            np.testing.assert_allclose(a.likelihood, b.likelihood, atol=1e-4)
            clear = np.abs(b.likelihood - threshold) > 1e-4  # pixels off the threshold
            goal_a, goal_b = a.likelihood >= threshold, b.likelihood >= threshold
            assert np.array_equal(goal_a[clear], goal_b[clear])
            assert abs(a.visible - b.visible) < 1e-4 and abs(a.room_match - b.room_match) < 1e-4
            assert (a.category_match is None) == (b.category_match is None)
            if b.category_match is not None:
                assert abs(a.category_match - b.category_match) < 1e-4
            assert (a.anchor is None) == (b.anchor is None)
            if b.anchor is not None:
                np.testing.assert_allclose(a.anchor, b.anchor, atol=1e-4)


def test_the_same_actions_in_closed_loop(agents):
    env = make_env({"split": "val", "semantic": False})
    actions = []
    try:
        for policy in agents:
            obs, _ = env.reset(options={"episode": 3})
            policy.reset()
            steps = []
            for _ in range(60):
                steps.append(policy.select_action(obs))
                obs, _, terminated, truncated, _ = env.step(steps[-1])
                if terminated or truncated:
                    break
            actions.append(np.stack(steps))  # (T, 3)
    finally:
        env.close()
    assert actions[0].shape == actions[1].shape and len(actions[0]) >= 30
    np.testing.assert_allclose(actions[0], actions[1], atol=1e-5)


def test_an_export_of_other_weights_is_refused_until_exported_again(tmp_path):
    folder = _copy(tmp_path)
    loaded = read_checkpoint(folder)
    tensors = dict(loaded.model)
    tensors["goal_head.pixel_logit.bias"] = tensors["goal_head.pixel_logit.bias"] + 0.1
    save_file(tensors, str(tmp_path / MODEL_FILE))  # new weights, the manifest kept right
    add_files(folder, {MODEL_FILE: (tmp_path / MODEL_FILE).read_bytes()}, {}, drop=[MODEL_FILE])
    stale = loaded.manifest[RECORD]["networks"]["goal_head"]["file"]
    with pytest.raises(
        CheckpointError,
        match=rf"{stale} was exported from other goal_head "
        rf"weights \(stale\); export again with `vla-gr export-onnx {folder}`",
    ):
        load_policy(folder)
    load_policy(folder, overrides=TORCH)  # PyTorch runs the weights as they are
    files = export_onnx(folder)
    assert stale not in {f.name for f in files} and not (folder / stale).exists()
    policy = load_policy(folder)
    listed = read_checkpoint(folder).manifest["files"]
    assert {f.name for f in files} <= set(listed)
    frame = {"rgb": torch.zeros(1, 3, 64, 64, dtype=torch.uint8), "depth": torch.ones(1, 1, 64, 64)}
    head = policy.goal_head
    inputs = head.network_inputs(frame["rgb"], frame["depth"], ["the chair"])
    with torch.no_grad():
        expected = head.network(*inputs)["pixel_logits"]
    got = policy.perception.networks["goal_head"](*inputs)["pixel_logits"]
    torch.testing.assert_close(got, expected, atol=1e-4, rtol=1e-4)


def test_a_tampered_or_missing_export_is_refused(tmp_path):
    folder = _copy(tmp_path)
    entry = read_checkpoint(folder).manifest[RECORD]["networks"]["room_type"]
    onnx = folder / entry["file"]
    data = bytearray(onnx.read_bytes())
    data[len(data) // 2] ^= 0xFF
    onnx.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match=rf"{entry['file']} fails its SHA-256 check"):
        load_policy(folder)
    shutil.rmtree(folder)
    folder = _copy(tmp_path)
    exports = read_checkpoint(folder).manifest[RECORD]["networks"].values()
    add_files(folder, {}, {RECORD: {}}, drop=[entry["file"] for entry in exports])
    with pytest.raises(
        CheckpointError,
        match=rf"no ONNX export of goal_head; write it with "
        rf"`vla-gr export-onnx {folder}`",
    ):
        load_policy(folder)


def test_export_onnx_command(tmp_path, capsys):
    from vla_gr.cli import main

    folder = _copy(tmp_path)
    before = read_checkpoint(folder).manifest
    assert main(["export-onnx", str(folder)]) == 0
    printed = capsys.readouterr().out.split()
    names = {e["file"] for e in before[RECORD]["networks"].values()}
    assert {Path(p).name for p in printed} == names  # the same weights: the same files
    assert read_checkpoint(folder).manifest["files"] == before["files"]
    assert main(["export-onnx", str(tmp_path / "nothing")]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0


def test_save_pretrained_writes_the_export_the_agent_runs(agents, tmp_path):
    onnx, _ = agents
    onnx.save_pretrained(tmp_path / "pretrained")
    again = load_policy(tmp_path / "pretrained")
    assert all(isinstance(n, OnnxNetwork) for n in again.perception.networks.values())
    files = read_checkpoint(tmp_path / "pretrained").manifest["files"]
    assert sorted(f for f in files if f.endswith(".onnx")) == sorted(
        p.name for p in SHIPPED.glob("*.onnx")
    )  # the same weights, the same files
