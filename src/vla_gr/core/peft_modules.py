"""Parameter-efficient fine-tuning of our own modules: LoRA, OFT, bottleneck adapters.

LoRA and OFT are peft's own layers, injected in place with
:func:`peft.inject_adapter_in_model`, so the model keeps its class and methods
(no ``PeftModel`` wrapper). Bottleneck adapters (Houlsby et al.) are implemented
here since peft has none. :func:`merge_peft` folds LoRA/OFT into the base
weights and returns a plain module for zero-overhead inference.

Target selection follows peft: a list of names matches a module whose full
name equals an entry or ends with ``"." + entry``; a single string is a regular
expression that must match the full name; ``"all-linear"`` selects every
``nn.Linear``. Unlike peft, *every* list entry must match something.

Applies to any module of :mod:`vla_gr.core` (attention projections first); next in the
data flow: merged weights serve inference with no overhead.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import torch
from peft import LoraConfig, OFTConfig, PeftModel, inject_adapter_in_model
from peft.tuners.tuners_utils import BaseTunerLayer
from safetensors.torch import load_file, save_file
from torch import nn

from vla_gr.validation import check_choice, check_positive_int

logger = logging.getLogger(__name__)

SPECS_ATTR = "_vla_gr_peft_specs"  # list of apply_* calls recorded on the model
_METADATA_KEY = "vla_gr_peft"
_ACTIVATIONS = {"gelu": nn.GELU, "relu": nn.ReLU, "silu": nn.SiLU, "tanh": nn.Tanh}


# --------------------------------------------------------------------------- bottleneck


class BottleneckAdapter(nn.Module):
    """Houlsby bottleneck adapter around a Linear layer.

    ``y = base(x);  out = y + scale * up(dropout(act(down(y))))`` with ``up``
    zero-initialised, so at init the wrapped layer computes exactly ``base(x)``.
    Not mergeable into the Linear: the nonlinearity between ``down`` and ``up``
    makes the map non-affine.
    """

    def __init__(
        self,
        base_layer: nn.Module,
        bottleneck_dim: int,
        activation: str = "gelu",
        dropout: float = 0.0,
        scale: float = 1.0,
    ) -> None:
        super().__init__()
        out_features = _base_linear(base_layer).out_features
        self.base_layer = base_layer
        self.adapter_down = nn.Linear(out_features, bottleneck_dim)
        self.adapter_act = _ACTIVATIONS[activation]()
        self.adapter_dropout = nn.Dropout(dropout)
        self.adapter_up = nn.Linear(bottleneck_dim, out_features)
        nn.init.zeros_(self.adapter_up.weight)
        nn.init.zeros_(self.adapter_up.bias)
        self.scale = scale
        self.adapter_enabled = True

    def adapter_parameters(self) -> Iterator[tuple[str, nn.Parameter]]:
        """``(local name, parameter)`` of the adapter's own weights."""
        for prefix in ("adapter_down", "adapter_up"):
            for name, p in getattr(self, prefix).named_parameters():
                yield f"{prefix}.{name}", p

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (..., in_features) -> (..., out_features)."""
        y = self.base_layer(x)  # (..., out)
        if not self.adapter_enabled:
            return y
        z = self.adapter_dropout(self.adapter_act(self.adapter_down(y)))  # (..., bottleneck)
        return y + self.scale * self.adapter_up(z)  # (..., out)


def _base_linear(module: nn.Module) -> nn.Linear:
    base = module.get_base_layer() if isinstance(module, BaseTunerLayer) else module
    if not isinstance(base, nn.Linear):
        raise ValueError(f"expected an nn.Linear target, got {type(base).__name__}")
    return base


# --------------------------------------------------------------------------- targets


def _internal_prefixes(model: nn.Module) -> list[str]:
    """Names of adapter wrappers whose children are adapter internals."""
    return [
        n
        for n, m in model.named_modules()
        if n and isinstance(m, (BaseTunerLayer, BottleneckAdapter))
    ]


def resolve_targets(
    model: nn.Module, target_modules: str | Sequence[str], types: tuple[type, ...] = (nn.Linear,)
) -> list[str]:
    """Full names of the modules selected by ``target_modules`` (see module docstring).

    Raises:
        ValueError: empty selection, an entry matching nothing, a match that is
            already adapted, or a match whose type is not in ``types``.
    """
    if isinstance(target_modules, str):
        if not target_modules:
            raise ValueError("target_modules must not be empty")
        entries: list[str] | None = None
    else:
        entries = list(target_modules)
        if not entries or not all(isinstance(e, str) and e for e in entries):
            raise ValueError(f"target_modules={target_modules!r} must be non-empty strings")
    inner = _internal_prefixes(model)
    candidates = [
        (n, m)
        for n, m in model.named_modules()
        if n and not any(n.startswith(p + ".") for p in inner)
    ]

    def matches(name: str, entry: str) -> bool:
        return name == entry or name.endswith("." + entry)

    modules = dict(candidates)
    # nn.MultiheadAttention reads out_proj.weight directly, bypassing a wrapper's forward.
    in_mha = {f"{n}.out_proj" for n, m in candidates if isinstance(m, nn.MultiheadAttention)}
    if target_modules == "all-linear":
        selected = [n for n, m in candidates if isinstance(m, nn.Linear) and n not in in_mha]
    elif entries is None:
        selected = [n for n, _ in candidates if re.fullmatch(target_modules, n)]
    else:
        unmatched = [e for e in entries if not any(matches(n, e) for n, _ in candidates)]
        if unmatched:
            linears = [n for n, m in candidates if isinstance(m, nn.Linear)][:20]
            raise ValueError(
                f"target_modules entries {unmatched} match no module of "
                f"{type(model).__name__}; Linear layers are: {linears}"
            )
        selected = [n for n, _ in candidates if any(matches(n, e) for e in entries)]
    if not selected:
        raise ValueError(f"target_modules={target_modules!r} selects no module")
    for name in selected:
        module = modules[name]
        if name in in_mha:
            raise ValueError(
                f"target module {name!r} is the out_proj of an nn.MultiheadAttention, which "
                "bypasses its forward; use an attention with q_proj/k_proj/v_proj/out_proj "
                "Linear layers (vla_gr.core.trajectory_attention)"
            )
        if isinstance(module, (BaseTunerLayer, BottleneckAdapter)):
            raise ValueError(f"target module {name!r} already carries an adapter")
        if not isinstance(module, types):
            raise ValueError(
                f"target module {name!r} is a {type(module).__name__}; supported: "
                f"{[t.__name__ for t in types]}"
            )
    return selected


def _exact_regex(names: Sequence[str]) -> str:
    return "^(?:" + "|".join(re.escape(n) for n in names) + ")$"


def _record(model: nn.Module, spec: dict[str, Any]) -> None:
    specs = list(getattr(model, SPECS_ATTR, []))
    specs.append(spec)
    object.__setattr__(model, SPECS_ATTR, specs)


def _adapter_param_names(model: nn.Module) -> set[str]:
    names = set()
    for mname, module in model.named_modules():
        prefix = f"{mname}." if mname else ""
        if isinstance(module, BaseTunerLayer):
            for attr in module.adapter_layer_names:
                for pname, _ in getattr(module, attr).named_parameters():
                    names.add(f"{prefix}{attr}.{pname}")
        elif isinstance(module, BottleneckAdapter):
            names.update(f"{prefix}{pname}" for pname, _ in module.adapter_parameters())
    return names


def _freeze_all_but_adapters(model: nn.Module) -> None:
    adapter = _adapter_param_names(model)
    for name, p in model.named_parameters():
        p.requires_grad_(name in adapter)


def _check_common(rank: int, adapter_name: str, model: nn.Module, key: str = "rank") -> None:
    check_positive_int(key, rank)
    if adapter_name in getattr(model, "peft_config", {}):
        raise ValueError(f"adapter_name={adapter_name!r} is already used in this model")


# --------------------------------------------------------------------------- apply


def apply_lora_to_model(
    model: nn.Module,
    target_modules: str | Sequence[str],
    rank: int = 8,
    alpha: float = 16.0,
    dropout: float = 0.0,
    adapter_name: str = "default",
    use_rslora: bool = False,
) -> nn.Module:
    """Inject peft LoRA (``W x + (alpha / rank) B A x``, ``B = 0`` at init) in place.

    Only adapter parameters stay trainable. Returns ``model`` itself.
    """
    _check_common(rank, adapter_name, model)
    if not alpha > 0:
        raise ValueError(f"alpha={alpha!r} must be > 0")
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"dropout={dropout!r} must be in [0, 1)")
    types = (nn.Linear, nn.Embedding, nn.Conv1d, nn.Conv2d)
    names = resolve_targets(model, target_modules, types)
    config = LoraConfig(
        r=rank,
        lora_alpha=alpha,
        lora_dropout=dropout,
        target_modules=_exact_regex(names),
        use_rslora=use_rslora,
    )
    inject_adapter_in_model(config, model, adapter_name=adapter_name)
    _freeze_all_but_adapters(model)
    _record(
        model,
        dict(
            method="lora",
            target_modules=names,
            rank=rank,
            alpha=alpha,
            dropout=dropout,
            adapter_name=adapter_name,
            use_rslora=use_rslora,
        ),
    )
    logger.info("LoRA r=%d alpha=%s on %d modules", rank, alpha, len(names))
    return model


def apply_oft_to_model(
    model: nn.Module,
    target_modules: str | Sequence[str],
    rank: int | None = None,
    block_size: int | None = None,
    adapter_name: str = "default",
    exact_cayley: bool = True,
    coft: bool = False,
    eps: float = 6e-5,
    block_share: bool = False,
) -> nn.Module:
    """Inject peft orthogonal fine-tuning (OFT) in place: ``y = W (R x) + b``.

    ``R`` is block-diagonal with ``r`` orthogonal blocks of size
    ``b x b`` (Cayley transform of skew-symmetric blocks, identity at init), and
    ``r * b == in_features`` for every target layer. Our ``rank`` is peft's
    ``OFTConfig.r`` (the number of blocks); passing ``block_size`` instead sets
    ``oft_block_size`` (peft accepts exactly one of the two and infers the other).
    Every target's ``in_features`` must be divisible by ``rank`` (or
    ``block_size``) with blocks of size >= 2; unlike peft, which silently adjusts
    a bad value, this raises. ``exact_cayley=True`` uses the exact Cayley map
    (``R^T R = I`` to float precision); False uses peft's faster truncated
    Cayley-Neumann series (approximately orthogonal). Returns ``model`` itself.
    """
    if (rank is None) == (block_size is None):
        raise ValueError(
            f"give exactly one of rank (number of blocks) or block_size, got rank={rank!r}, "
            f"block_size={block_size!r}"
        )
    count = rank if rank is not None else block_size
    key = "rank" if rank is not None else "block_size"
    _check_common(count, adapter_name, model, key)
    names = resolve_targets(model, target_modules, (nn.Linear,))
    modules = dict(model.named_modules())
    for name in names:
        in_features = modules[name].in_features
        if in_features % count != 0 or in_features // count < (2 if rank is not None else 1):
            raise ValueError(
                f"{key}={count} does not divide in_features={in_features} of {name!r} into "
                f"blocks of size >= 2 (OFT needs r * block_size == in_features)"
            )
        if block_size is not None and block_size < 2:
            raise ValueError(f"block_size={block_size} must be >= 2")
    config = OFTConfig(
        r=rank or 0,
        oft_block_size=block_size or 0,
        target_modules=_exact_regex(names),
        use_cayley_neumann=not exact_cayley,
        coft=coft,
        eps=eps,
        block_share=block_share,
    )
    inject_adapter_in_model(config, model, adapter_name=adapter_name)
    _freeze_all_but_adapters(model)
    _record(
        model,
        dict(
            method="oft",
            target_modules=names,
            rank=rank,
            block_size=block_size,
            adapter_name=adapter_name,
            exact_cayley=exact_cayley,
            coft=coft,
            eps=eps,
            block_share=block_share,
        ),
    )
    logger.info("OFT %s=%d on %d modules", key, count, len(names))
    return model


def apply_adapter_to_model(
    model: nn.Module,
    target_modules: str | Sequence[str],
    bottleneck_dim: int = 16,
    activation: str = "gelu",
    dropout: float = 0.0,
    scale: float = 1.0,
) -> nn.Module:
    """Wrap target Linear layers in :class:`BottleneckAdapter` (in place).

    Only adapter parameters stay trainable. Returns ``model`` itself.
    """
    check_positive_int("bottleneck_dim", bottleneck_dim)
    check_choice("activation", activation, _ACTIVATIONS)
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"dropout={dropout!r} must be in [0, 1)")
    names = resolve_targets(model, target_modules, (nn.Linear,))
    for name in names:
        parent, attr = _parent(model, name)
        layer = getattr(parent, attr)
        adapter = BottleneckAdapter(layer, bottleneck_dim, activation, dropout, scale)
        adapter.to(device=layer.weight.device, dtype=layer.weight.dtype)
        setattr(parent, attr, adapter)
    _freeze_all_but_adapters(model)
    _record(
        model,
        dict(
            method="bottleneck",
            target_modules=names,
            bottleneck_dim=bottleneck_dim,
            activation=activation,
            dropout=dropout,
            scale=scale,
        ),
    )
    logger.info("bottleneck adapters (dim %d) on %d modules", bottleneck_dim, len(names))
    return model


def _parent(model: nn.Module, name: str) -> tuple[nn.Module, str]:
    parent_name, _, attr = name.rpartition(".")
    return (model.get_submodule(parent_name) if parent_name else model), attr


_APPLY = {
    "lora": apply_lora_to_model,
    "oft": apply_oft_to_model,
    "bottleneck": apply_adapter_to_model,
}


# --------------------------------------------------------------------------- utilities


class ParameterCount(NamedTuple):
    """``(trainable, total)`` parameter counts."""

    trainable: int
    total: int

    @property
    def fraction(self) -> float:
        """Trainable share of all parameters."""
        return self.trainable / self.total if self.total else 0.0


def trainable_parameters(model: nn.Module) -> ParameterCount:
    """Count trainable and total parameters (shared parameters counted once)."""
    trainable = total = 0
    for p in model.parameters():
        total += p.numel()
        trainable += p.numel() if p.requires_grad else 0
    return ParameterCount(trainable, total)


def set_adapters_enabled(model: nn.Module, enabled: bool) -> None:
    """Switch every adapter (peft and bottleneck) on or off; off = the base model."""
    for module in model.modules():
        if isinstance(module, BaseTunerLayer):
            module.enable_adapters(enabled)
        elif isinstance(module, BottleneckAdapter):
            module.adapter_enabled = enabled


@contextlib.contextmanager
def adapters_disabled(model: nn.Module) -> Iterator[nn.Module]:
    """Context in which ``model`` computes its base (adapter-free) output."""
    set_adapters_enabled(model, False)
    try:
        yield model
    finally:
        set_adapters_enabled(model, True)


def oft_rotation(layer: nn.Module, adapter_name: str = "default") -> torch.Tensor:
    """The block-diagonal rotation ``R`` (in_features, in_features) of a peft OFT layer.

    The layer computes ``base(x @ R)``; merging sets ``W <- W R^T``.
    """
    if not (isinstance(layer, BaseTunerLayer) and hasattr(layer, "oft_R")):
        raise ValueError(f"layer must be a peft OFT layer, got {type(layer).__name__}")
    if adapter_name not in layer.oft_R:
        raise ValueError(f"adapter_name={adapter_name!r} not in layer ({list(layer.oft_R)})")
    return layer.get_delta_weight(adapter_name)  # (in, in)


def merge_peft(model: nn.Module, bottleneck: str = "keep", safe_merge: bool = True) -> nn.Module:
    """Fold LoRA/OFT into the base weights and remove every peft wrapper.

    Args:
        model: a model with injected adapters (or a ``peft.PeftModel``).
        bottleneck: ``"keep"`` leaves bottleneck adapters in place (they are not
            mergeable: a nonlinearity sits between their projections) or
            ``"raise"`` refuses with ValueError.
        safe_merge: check merged weights for NaN/inf.

    Returns:
        The plain ``nn.Module`` (the same object, modified in place, unless a
        ``PeftModel`` was given, whose base model is returned).
    """
    if bottleneck not in ("keep", "raise"):
        raise ValueError(f"bottleneck={bottleneck!r} is not valid; choose 'keep' or 'raise'")
    bottlenecks = [n for n, m in model.named_modules() if isinstance(m, BottleneckAdapter)]
    if bottlenecks and bottleneck == "raise":
        raise ValueError(
            f"bottleneck adapters at {bottlenecks} cannot be merged into Linear weights "
            "(nonlinear); pass bottleneck='keep' to keep them as modules"
        )
    if isinstance(model, PeftModel):
        model = model.merge_and_unload(safe_merge=safe_merge)
    tuner_layers = [(n, m) for n, m in model.named_modules() if isinstance(m, BaseTunerLayer)]
    for name, layer in tuner_layers:
        layer.enable_adapters(True)
        layer.merge(safe_merge=safe_merge)
        base = layer.get_base_layer()
        if name:
            parent, attr = _parent(model, name)
            setattr(parent, attr, base)
        else:
            model = base
    for attr in ("peft_config", "_hf_peft_config_loaded"):
        if attr in model.__dict__:
            delattr(model, attr)
    specs = [s for s in getattr(model, SPECS_ATTR, []) if s["method"] == "bottleneck"]
    object.__setattr__(model, SPECS_ATTR, specs)
    if bottlenecks:
        logger.warning("kept %d non-mergeable bottleneck adapters", len(bottlenecks))
    return model


# --------------------------------------------------------------------------- save / load


def adapter_state_dict(model: nn.Module) -> dict[str, torch.Tensor]:
    """Adapter weights only, keyed as in ``model.state_dict()``."""
    names = _adapter_param_names(model)
    return {k: v for k, v in model.state_dict().items() if k in names}


def save_adapter(model: nn.Module, path: str | Path) -> Path:
    """Write the adapter weights alone (+ how they were applied) to a safetensors file."""
    state = {k: v.detach().cpu().contiguous() for k, v in adapter_state_dict(model).items()}
    if not state:
        raise ValueError("model has no adapter weights to save")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    specs = json.dumps(getattr(model, SPECS_ATTR, []))
    tmp = path.with_name(path.name + ".tmp")
    save_file(state, str(tmp), metadata={"format": "pt", _METADATA_KEY: specs})
    tmp.replace(path)
    return path


def load_adapter(model: nn.Module, path: str | Path) -> nn.Module:
    """Load adapter weights saved by :func:`save_adapter` into ``model``.

    A model without adapters first gets them re-applied from the file's record
    of the ``apply_*`` calls. Keys and shapes must match exactly.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"path={str(path)!r} is not a file")
    state = load_file(str(path))
    if not _adapter_param_names(model):
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as f:
            specs = json.loads((f.metadata() or {}).get(_METADATA_KEY, "[]"))
        if not specs:
            raise ValueError(f"{path} records no adapter specs and the model has no adapters")
        for spec in specs:
            spec = dict(spec)
            _APPLY[spec.pop("method")](model, **spec)
    expected = adapter_state_dict(model)
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        raise ValueError(
            f"adapter file {path} does not fit the model: missing {missing[:5]}, "
            f"unexpected {unexpected[:5]}"
        )
    for key, tensor in state.items():
        if tensor.shape != expected[key].shape:
            raise ValueError(
                f"adapter weight {key!r} has shape {tuple(tensor.shape)}, model expects "
                f"{tuple(expected[key].shape)}"
            )
    model.load_state_dict(state, strict=False)
    return model
