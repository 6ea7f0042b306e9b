"""Policies in huggingface_hub's conventions: ``save_pretrained`` writes a pretrained folder
(``config.json``, ``model.safetensors``, a model card, ``manifest.json``) and
``from_pretrained`` (a folder, or a repo id in the local Hugging Face cache) reads it back
verified, refusing a tampered, missing or unknown thing in one line naming it."""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from huggingface_hub import ModelCard, PyTorchModelHubMixin, hf_hub_download
from omegaconf import OmegaConf

from vla_gr.checkpoint import CheckpointError, sha256_file
from vla_gr.policy import EndToEndPolicy, NavigationPolicy, VLAGRPolicy

DATA = Path(__file__).parent / "data"
TINY = DATA / "end_to_end_tiny"  # a training checkpoint (config.yaml layout)
HUB_FILES = {"config.json", "model.safetensors", "README.md", "manifest.json"}


@pytest.fixture(scope="module")
def policy() -> NavigationPolicy:
    return NavigationPolicy.from_pretrained(TINY)


@pytest.fixture
def saved(policy, tmp_path) -> Path:
    folder = tmp_path / "tiny"
    policy.save_pretrained(folder)
    return folder


def _observation() -> dict:
    """One observation of the tiny policy's recorded episode (32 px)."""
    rec = np.load(DATA / "end_to_end_tiny_actions.npz")
    return {
        "rgb": rec["rgb"][0],  # (H, W, 3) uint8
        "depth": rec["depth"][0],  # (H, W, 1) float32
        "pose": rec["pose"][0],  # (3,)
        "instruction": str(rec["instruction"]),
    }


def _act(policy: NavigationPolicy, obs: dict) -> np.ndarray:
    torch.manual_seed(0)
    policy.reset()
    return policy.select_action(obs)  # (3,)


def _resign(folder: Path, fname: str) -> None:
    """Write ``fname``'s new SHA-256 and size into the manifest (a consistent folder)."""
    manifest = json.loads((folder / "manifest.json").read_text())
    file = folder / fname
    manifest["files"][fname] = {"sha256": sha256_file(file), "bytes": file.stat().st_size}
    (folder / "manifest.json").write_text(json.dumps(manifest))


def _refused(folder: Path, pattern: str) -> str:
    with pytest.raises(CheckpointError, match=pattern) as err:
        NavigationPolicy.from_pretrained(folder)
    assert "\n" not in str(err.value)
    return str(err.value)


def test_round_trip_gives_identical_tensors_and_actions(policy, saved, monkeypatch):
    def unpickle(*args, **kwargs):
        raise AssertionError("loading unpickled something")

    for module, name in ((torch, "load"), (pickle, "load"), (pickle, "loads")):
        monkeypatch.setattr(module, name, unpickle)
    back = NavigationPolicy.from_pretrained(saved)  # the base class builds the agent named
    assert type(back) is EndToEndPolicy and not back.training
    assert back.config == policy.config
    before, after = policy.state_dict(), back.state_dict()
    assert before.keys() == after.keys()
    assert all(torch.equal(before[k], after[k]) for k in before)
    obs = _observation()
    np.testing.assert_array_equal(_act(back, obs), _act(policy, obs))
    with pytest.raises(CheckpointError, match=r"holds model.agent=end_to_end.*not a VLAGRPolicy"):
        VLAGRPolicy.from_pretrained(saved)


def test_the_folder_is_what_huggingface_hub_expects(policy, saved):
    assert {p.name for p in saved.iterdir()} == HUB_FILES
    manifest = json.loads((saved / "manifest.json").read_text())
    assert set(manifest["files"]) == HUB_FILES - {"manifest.json"}
    config = json.loads((saved / "config.json").read_text())  # the model section, every key
    assert config == OmegaConf.to_container(OmegaConf.structured(policy.config))
    # the mixin's own safetensors loader fills a new policy of that config exactly
    fresh = PyTorchModelHubMixin._load_as_safetensor(
        EndToEndPolicy(policy.config), str(saved / "model.safetensors"), "cpu", True
    )
    assert all(torch.equal(v, policy.state_dict()[k]) for k, v in fresh.state_dict().items())
    card = ModelCard.load(saved / "README.md")
    assert card.data.library_name == "vla-gr" and "pytorch_model_hub_mixin" in card.data.tags
    assert "EndToEndPolicy" in card.text and "NavigationPolicy.from_pretrained" in card.text


def test_a_repo_id_loads_from_the_local_hugging_face_cache(policy, saved, tmp_path):
    cache = tmp_path / "hf-cache"
    repo = cache / "models--vla-gr--tiny"
    commit = "0123456789abcdef0123456789abcdef01234567"
    (repo / "refs").mkdir(parents=True)
    (repo / "refs" / "main").write_text(commit)
    snapshot = repo / "snapshots" / commit
    snapshot.mkdir(parents=True)
    (repo / "blobs").mkdir()
    for file in saved.iterdir():  # the cache's layout: snapshot files link to blobs
        blob = repo / "blobs" / hashlib.sha256(file.read_bytes()).hexdigest()
        shutil.copy(file, blob)
        (snapshot / file.name).symlink_to(Path("..", "..", "blobs", blob.name))
    config = hf_hub_download("vla-gr/tiny", "config.json", cache_dir=cache, local_files_only=True)
    assert Path(config).read_text() == (saved / "config.json").read_text()
    back = NavigationPolicy.from_pretrained("vla-gr/tiny", cache_dir=cache, local_files_only=True)
    assert type(back) is EndToEndPolicy and back.config == policy.config
    with pytest.raises(CheckpointError, match=r"checkpoint vla-gr/missing: no such folder"):
        NavigationPolicy.from_pretrained("vla-gr/missing", cache_dir=cache, local_files_only=True)


def test_a_tampered_byte_is_refused_naming_the_file(saved):
    data = bytearray((saved / "model.safetensors").read_bytes())
    data[-1] ^= 0x01  # the last byte of the last tensor: same size, other weights
    (saved / "model.safetensors").write_bytes(bytes(data))
    _refused(saved, r"model\.safetensors fails its SHA-256 check")


@pytest.mark.parametrize("fname", ["model.safetensors", "config.json", "README.md"])
def test_a_missing_file_is_refused_naming_it(saved, fname):
    (saved / fname).unlink()
    _refused(saved, rf"{fname} is missing")


def test_config_json_with_an_unknown_or_missing_key_is_refused_naming_it(saved):
    config = json.loads((saved / "config.json").read_text())
    config["head"]["warp_factor"] = 9
    (saved / "config.json").write_text(json.dumps(config))
    _resign(saved, "config.json")
    _refused(saved, r"config\.json has head\.warp_factor, which this version does not know")
    del config["head"]["warp_factor"], config["head"]["num_inference_steps"]
    (saved / "config.json").write_text(json.dumps(config))
    _resign(saved, "config.json")
    _refused(saved, r"config\.json lacks head\.num_inference_steps")


def test_saving_replaces_a_checkpoint_but_no_other_folder(policy, saved, tmp_path):
    policy.save_pretrained(saved)  # saved again: replaced whole
    assert {p.name for p in saved.iterdir()} == HUB_FILES
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp-")]
    other = tmp_path / "notes"
    other.mkdir()
    (other / "todo.txt").write_text("keep me")
    with pytest.raises(CheckpointError, match=rf"{other} exists and is not a checkpoint"):
        policy.save_pretrained(other)
    assert (other / "todo.txt").read_text() == "keep me"
    with pytest.raises(ValueError, match="pass no config"):
        policy.save_pretrained(tmp_path / "with-config", config={"horizon": 4})
