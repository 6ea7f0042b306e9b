"""The agent shipped in ``checkpoints/vla_gr_cpu``: it loads, verifies and beats ``random``."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from vla_gr.checkpoint import read_checkpoint
from vla_gr.configs import load_config
from vla_gr.evaluate import evaluate, expand_aliases
from vla_gr.policy import VLAGRPolicy, load_policy
from vla_gr.policy.factory import model_key_gaps

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"


def test_shipped_checkpoint_is_the_dual_system_and_small():
    policy = load_policy(SHIPPED)  # verifies the SHA-256 manifest
    assert type(policy) is VLAGRPolicy and policy.dual_system.plan_every == 3
    # S2's room check is on: a trained room-type classifier and a rejection threshold
    assert policy.room_type is not None and policy.perception.room_type is policy.room_type
    assert 0.0 < policy.config.navigator.goal_checks.room_reject_threshold < 0.5
    # and its object checks: a trained segmenter, the category threshold, the relation distance
    assert policy.object_category is not None
    assert policy.perception.object_category is policy.object_category
    assert 0.0 < policy.config.navigator.goal_checks.object_reject_threshold < 0.5
    size = sum(f.stat().st_size for f in SHIPPED.rglob("*") if f.is_file())
    assert size <= 20 * 2**20


def test_shipped_checkpoint_carries_every_model_key_and_its_weights_are_unchanged():
    loaded = read_checkpoint(SHIPPED)
    saved = OmegaConf.to_container(OmegaConf.create(loaded.config_yaml).model)
    assert model_key_gaps(saved) == ([], [])
    assert saved["instruction_reader"]["enabled"]
    reader = sorted(k for k in loaded.model if k.startswith("instruction_reader."))
    parts = ("instruction_reader.tagger.", "instruction_reader.intent.")
    assert reader and all(k.startswith(parts) for k in reader)
    assert saved["instruction_reader"]["intent"]  # the request intent head, weights included
    assert any(k.startswith("instruction_reader.intent.") for k in reader)
    # every other weight is the agent's before the reader was added, bit for bit (the file
    # model.safetensors of that agent had SHA-256 953290197333eec1...)
    digest = hashlib.sha256()
    for name in sorted(k for k in loaded.model if k not in reader):
        digest.update(name.encode())
        digest.update(loaded.model[name].contiguous().numpy().tobytes())
    assert digest.hexdigest() == "ac5828c32e595866e2b7049614c04b6e71d271620ca198d2ced446c2de5904f0"


def _run(tmp_path: Path, agent: str, episodes: int) -> dict:
    args = [f"output_dir={tmp_path / agent}", f"agent={agent}", f"num_episodes={episodes}",
            f"checkpoint={SHIPPED}", "workers=2", "eval.progress=false",
            "eval.video_successes=0", "eval.video_per_cause=0"]  # fmt: skip
    return evaluate(load_config("config_cpu", expand_aliases(args))[1])["metrics"]


def test_shipped_agent_beats_random_by_a_wide_margin(tmp_path):
    # val 0-9 are deterministic episodes: measured SR 0.9 / SPL 0.652 against 0.0 / 0.0
    agent, rand = _run(tmp_path, "checkpoint", 10), _run(tmp_path, "random", 10)
    assert agent["success"] >= rand["success"] + 0.6 and agent["spl"] >= rand["spl"] + 0.4


@pytest.mark.slow
def test_shipped_agent_on_100_val_episodes(tmp_path):
    # val 120-319: 0.875; test 0-499: 0.890
    assert _run(tmp_path, "checkpoint", 100)["success"] >= 0.75


def test_inference_settings_can_change_on_load_and_export(tmp_path):
    from vla_gr.configs import ConfigError
    from vla_gr.policy.export import export_pretrained

    policy = VLAGRPolicy.from_pretrained(SHIPPED, overrides=["navigator.confirmation.ticks=4"])
    assert policy.dual_system.navigator.config.confirmation.ticks == 4
    with pytest.raises(ConfigError, match="settings no weight depends on"):
        VLAGRPolicy.from_pretrained(SHIPPED, overrides=["goal_head.stem_channels=8"])
    out = export_pretrained(SHIPPED, tmp_path / "exported", ["pursuit.lookahead=0.8"])
    assert sorted(p.name for p in out.iterdir() if p.suffix != ".onnx") == [
        "config.yaml", "manifest.json", "model.safetensors", "trainer_state.json"
    ]  # fmt: skip
    # its perception runs with ONNX Runtime: the export is written again, the same files
    onnx = sorted(p.name for p in SHIPPED.glob("*.onnx"))
    assert len(onnx) == 3 and sorted(p.name for p in out.glob("*.onnx")) == onnx
    again = VLAGRPolicy.from_pretrained(out)
    assert again.dual_system.follower.config.lookahead == 0.8
    earlier = read_checkpoint(SHIPPED).state.get("export_overrides", [])
    (out / "eval_results.md").write_text("measured")
    export_pretrained(out, out, ["navigator.confirmation.ticks=3"])  # in place: the record grows
    assert (out / "eval_results.md").read_text() == "measured"  # the folder's own file stays
    state = read_checkpoint(out).state
    assert state["export_overrides"] == [
        *earlier,
        "pursuit.lookahead=0.8",
        "navigator.confirmation.ticks=3",
    ]
    assert state["exported_from"] == str(SHIPPED)
    for (name, a), (_, b) in zip(policy.state_dict().items(), again.state_dict().items()):
        assert torch.equal(a, b), name  # the same weights
