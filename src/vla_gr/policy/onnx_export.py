"""The ONNX export of an agent's perception networks, kept in its checkpoint folder.

    vla-gr export-onnx checkpoints/vla_gr_cpu

writes ``<network>-<sha>.onnx`` (the goal head, the room-type classifier, the object-category
segmenter: each network ``model.perception.engine=onnxruntime`` runs,
:mod:`vla_gr.agent.perception.engine`) into the folder, lists the files in its
``manifest.json`` (SHA-256 and size, like every file) and records under the manifest's
``onnx`` key which file holds which network and the digest of the weights it was exported
from. Each export is checked against PyTorch on a probe frame before it is written.

Loading an agent with ``engine=onnxruntime`` (:func:`onnx_networks`) refuses, in one line
naming the file and this command, an export whose weights differ from the checkpoint's
(stale), and a checkpoint without one. A file's name carries its content's hash, so a
re-export never rewrites a listed file in place (:func:`vla_gr.checkpoint.add_files`).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

from vla_gr.agent.perception.engine import OPSET, OnnxNetwork, export_network, weights_digest
from vla_gr.checkpoint import CheckpointError, LoadedCheckpoint, add_files, read_checkpoint

log = logging.getLogger(__name__)

__all__ = [
    "RECORD",
    "TOLERANCE",
    "export_onnx",
    "onnx_networks",
    "probe_inputs",
    "tick_observations",
]

#: The manifest key of the export's record.
RECORD = "onnx"
#: Largest absolute difference of an export's outputs from PyTorch's on the probe frame.
TOLERANCE = 1e-4
_INPUT_NAMES = {"goal_head": ("x", "text"), "room_type": ("x",), "object_category": ("x",)}


def _command(path) -> str:
    return f"vla-gr export-onnx {path}"


def probe_inputs(
    name: str, module: nn.Module, image_size: int, seed: int = 0
) -> tuple[torch.Tensor, ...]:
    """The inputs of network ``name``'s ``module.network`` for a random RGB-D frame (batch 1)
    and, for the goal head, the request "the chair"."""
    g = torch.Generator().manual_seed(seed)
    rgb = torch.randint(0, 256, (1, 3, image_size, image_size), generator=g, dtype=torch.uint8)
    depth = 5.0 * torch.rand(1, 1, image_size, image_size, generator=g)  # (1, 1, S, S) m
    said = (["the chair"],) if name == "goal_head" else ()
    with torch.no_grad():
        return module.network_inputs(rgb, depth, *said)


def _checked_export(name: str, module: nn.Module, image_size: int) -> bytes:
    """``module``'s export, refused when it differs from PyTorch on the probe frame."""
    inputs = probe_inputs(name, module, image_size)
    data = export_network(module, inputs, _INPUT_NAMES[name])
    with torch.no_grad():
        expected = module.network(*inputs)
    got = OnnxNetwork(data)(*inputs)
    for key, value in expected.items():
        error = float((got[key] - value).abs().max())
        if error > TOLERANCE:
            raise RuntimeError(f"the ONNX export of {name} differs from PyTorch ({key}: {error})")
    return data


def export_onnx(path: str | Path) -> list[Path]:
    """Write the ONNX export of the perception networks of the agent at checkpoint folder
    ``path`` into it (an earlier export replaced); returns the files of the export."""
    from vla_gr.policy.factory import load_policy
    from vla_gr.policy.vla_gr import VLAGRPolicy

    path = Path(path)
    loaded = read_checkpoint(path)
    policy = load_policy(path, overrides=["perception.engine=torch"], expected=VLAGRPolicy)
    previous = loaded.manifest.get(RECORD, {}).get("networks", {})
    listed = loaded.manifest["files"]
    files: dict[str, bytes] = {}
    networks = {}
    for name, module in policy.perception_networks().items():
        data = _checked_export(name, module, policy.config.image_size)
        fname = f"{name}-{hashlib.sha256(data).hexdigest()[:12]}.onnx"
        if fname not in listed:
            files[fname] = data
        networks[name] = {"file": fname, "weights_sha256": weights_digest(module)}
        log.info("%s: %s (%d bytes)", name, fname, len(data))
    kept = {entry["file"] for entry in networks.values()}
    drop = [e["file"] for e in previous.values() if e["file"] not in kept and e["file"] in listed]
    record = {"opset": OPSET, "torch": torch.__version__, "networks": networks}
    add_files(path, files, {RECORD: record}, drop=drop)
    return [path / entry["file"] for entry in networks.values()]


def onnx_networks(loaded: LoadedCheckpoint, modules: Mapping[str, nn.Module]) -> dict:
    """ONNX Runtime sessions (:class:`~vla_gr.agent.perception.engine.OnnxNetwork`) of the
    export in checkpoint ``loaded`` for each of ``modules`` (name -> the loaded network);
    CheckpointError when one is missing or was exported from other weights."""
    path = loaded.path
    networks = loaded.manifest.get(RECORD, {}).get("networks", {})
    out = {}
    for name, module in modules.items():
        entry = networks.get(name)
        if entry is None:
            raise CheckpointError(
                f"checkpoint {path}: model.perception.engine=onnxruntime and no ONNX export of "
                f"{name}; write it with `{_command(path)}`"
            )
        if entry["file"] not in loaded.manifest["files"]:
            raise CheckpointError(
                f"checkpoint {path}: manifest.json lists no {entry['file']} (the {name} export); "
                f"export again with `{_command(path)}`"
            )
        if entry["weights_sha256"] != weights_digest(module):
            raise CheckpointError(
                f"checkpoint {path}: {entry['file']} was exported from other {name} weights "
                f"(stale); export again with `{_command(path)}`"
            )
        out[name] = OnnxNetwork(path / entry["file"])
    return out


def tick_observations(policy, episodes, steps: int, split: str = "val") -> list[dict]:
    """The observations ``policy`` (a dual-system agent) plans from at its S2 ticks in its
    first ``steps`` steps of each of ``episodes`` (indices of ``split``): the real frames an
    export is compared with PyTorch on."""
    from vla_gr.data.collect import make_env  # the env and the collectors import the policy

    env = make_env({"split": split, "semantic": False})
    seen = []
    try:
        for episode in episodes:
            obs, _ = env.reset(options={"episode": episode})
            policy.reset()
            for step in range(steps):
                if step % policy.dual_system.plan_every == 0:
                    seen.append(obs)
                obs, _, terminated, truncated, _ = env.step(policy.select_action(obs))
                if terminated or truncated:
                    break
    finally:
        env.close()
    return seen
