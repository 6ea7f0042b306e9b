"""Which inference engine runs S2's perception networks: one seam, PyTorch or ONNX Runtime.

Each perception network (the goal head, the room-type classifier, the object-category
segmenter) splits its call in three: ``network_inputs`` (the shared pre-processing: RGB-D
scaled to [-1, 1], the instruction's embedding), ``network`` (named tensors in, named tensors
out: the convolutions, what an engine runs) and the shared post-processing of its
``probabilities`` (sigmoid, category gate, test-time flip, softmax). ``model.perception.engine``
picks what runs ``network`` at inference:

- ``torch``: the module's own ``network``: the reference, and what training runs;
- ``onnxruntime``: an ONNX Runtime session (:class:`OnnxNetwork`) of the network's export
  (:func:`export_network`), on one thread with every graph optimisation. It is read from the
  agent's checkpoint (:mod:`vla_gr.policy.onnx_export`), tied there to the digest of the
  weights it was exported from (:func:`weights_digest`).

The shipped agent runs ``onnxruntime``: its perception takes about 0.6x PyTorch's time with
the same decisions (``benchmarks/bench_perception_engine.py``; docs/experiments.md).
"""

from __future__ import annotations

import hashlib
import io
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from vla_gr.errors import ConfigError
from vla_gr.validation import check_choice

__all__ = [
    "ENGINES",
    "Network",
    "OnnxNetwork",
    "PerceptionConfig",
    "export_network",
    "not_loaded",
    "weights_digest",
]

ENGINES = ("torch", "onnxruntime")
#: The ONNX opset of the exports (ONNX Runtime 1.16+ runs it).
OPSET = 17

#: ``network(*inputs) -> {name: tensor}``: a module's ``network`` or an engine's run of it.
Network = Callable[..., dict[str, torch.Tensor]]


@dataclass
class PerceptionConfig:
    """How S2's perception runs its networks (``model.perception.*``); no weight depends on it."""

    # torch (the reference, training) | onnxruntime (the checkpoint's ONNX export, one thread)
    engine: str = "torch"

    def __post_init__(self) -> None:
        check_choice("model.perception.engine", self.engine, ENGINES)


def weights_digest(module: nn.Module) -> str:
    """Hex SHA-256 of ``module``'s state dict: each entry's name and bytes, names sorted."""
    digest = hashlib.sha256()
    state = module.state_dict()
    for name in sorted(state):
        digest.update(name.encode())
        digest.update(state[name].detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


class _Graph(nn.Module):
    """``module.network`` as a module whose forward returns its outputs as a tuple."""

    def __init__(self, module: nn.Module, outputs: Sequence[str]) -> None:
        super().__init__()
        self.module, self.outputs = module, list(outputs)

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = self.module.network(*inputs)
        return tuple(out[name] for name in self.outputs)


def export_network(
    module: nn.Module, inputs: Sequence[torch.Tensor], input_names: Sequence[str]
) -> bytes:
    """The ONNX model (bytes) of ``module.network`` traced on example ``inputs`` (named
    ``input_names``); batch, height and width stay free (image inputs are (B, C, H, W)).
    Its outputs keep the names of the dict ``network`` returns."""
    try:
        import onnx  # torch's exporter writes the model with it
    except ImportError:
        raise ConfigError(
            "the ONNX export needs the onnx package: pip install 'vla-gr[onnx]' (make setup "
            "installs it)"
        ) from None
    if len(inputs) != len(input_names):
        raise ValueError(f"{len(inputs)} inputs for the names {list(input_names)}")
    was_training = module.training
    module.eval()
    try:
        with torch.no_grad():
            outputs = list(module.network(*inputs))
        axes = {}
        for name, x in zip(input_names, inputs):
            axes[name] = {0: "batch", 2: "height", 3: "width"} if x.dim() == 4 else {0: "batch"}
        buffer = io.BytesIO()
        with warnings.catch_warnings():  # the TorchScript exporter: no onnxscript needed
            warnings.simplefilter("ignore")
            torch.onnx.export(
                _Graph(module, outputs),
                tuple(inputs),
                buffer,
                input_names=list(input_names),
                output_names=outputs,
                dynamic_axes=axes,
                opset_version=OPSET,
                dynamo=False,
            )
    finally:
        module.train(was_training)
    onnx.checker.check_model(onnx.load_from_string(buffer.getvalue()))
    return buffer.getvalue()


class OnnxNetwork:
    """An exported network run by ONNX Runtime on one thread, called like the module's
    ``network``: tensors in (any device), ``{output name: tensor}`` out on the first input's
    device. ``model``: the ``.onnx`` file or its bytes."""

    def __init__(self, model: Path | bytes) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        source = str(model) if isinstance(model, Path) else model
        self.session = ort.InferenceSession(source, options, providers=["CPUExecutionProvider"])
        self.inputs = [i.name for i in self.session.get_inputs()]
        self.outputs = [o.name for o in self.session.get_outputs()]

    def __call__(self, *inputs: torch.Tensor) -> dict[str, torch.Tensor]:
        if len(inputs) != len(self.inputs):
            raise ValueError(f"the export takes {self.inputs}; got {len(inputs)} inputs")
        feeds = {
            name: np.ascontiguousarray(x.detach().cpu().numpy(), dtype=np.float32)
            for name, x in zip(self.inputs, inputs)
        }
        device = inputs[0].device
        results = self.session.run(self.outputs, feeds)
        return {n: torch.from_numpy(r).to(device) for n, r in zip(self.outputs, results)}


def not_loaded(name: str) -> Network:
    """The stand-in for network ``name`` of an ``onnxruntime`` agent whose export is not
    loaded yet (one built in memory, not from a checkpoint): calling it is a ConfigError."""

    def run(*inputs: torch.Tensor) -> dict[str, torch.Tensor]:
        raise ConfigError(
            f"model.perception.engine=onnxruntime runs the {name} of a checkpoint's ONNX export "
            "and none is loaded: load the agent from its checkpoint (load_policy / "
            "from_pretrained) or set model.perception.engine=torch"
        )

    return run
