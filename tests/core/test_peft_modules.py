"""PEFT on our own modules, tested the way peft tests itself."""

from __future__ import annotations

import copy

import pytest
import torch
from peft.tuners.tuners_utils import BaseTunerLayer
from safetensors.torch import load_file
from torch import nn

from vla_gr.core.peft_modules import (
    BottleneckAdapter,
    adapter_state_dict,
    adapters_disabled,
    apply_adapter_to_model,
    apply_lora_to_model,
    apply_oft_to_model,
    load_adapter,
    merge_peft,
    oft_rotation,
    save_adapter,
    trainable_parameters,
)

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


class TinyMLP(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.fc1 = nn.Linear(8, 16)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(16, 8)
        self.head = nn.Linear(8, 4)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, 8) -> (B, 4)."""
        return self.head(x + self.fc2(self.act(self.fc1(x))))


class TinyAttention(nn.Module):
    """Self-attention with q_proj/k_proj/v_proj/out_proj, reduced to (B, 4)."""

    def __init__(self, dim: int = 16, heads: int = 2) -> None:
        super().__init__()
        self.heads = heads
        self.q_proj = nn.Linear(dim, dim)
        self.k_proj = nn.Linear(dim, dim)
        self.v_proj = nn.Linear(dim, dim)
        self.out_proj = nn.Linear(dim, dim)
        self.readout = nn.Linear(dim, 4)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, T, D) -> (B, 4)."""
        B, T, D = x.shape

        def split(t):
            return t.view(B, T, self.heads, D // self.heads).transpose(1, 2)  # (B, h, T, d)

        q, k, v = split(self.q_proj(x)), split(self.k_proj(x)), split(self.v_proj(x))
        out = nn.functional.scaled_dot_product_attention(q, k, v)  # (B, h, T, d)
        out = self.out_proj(out.transpose(1, 2).reshape(B, T, D))  # (B, T, D)
        return self.readout(out.mean(1))  # (B, 4)


MODELS = {
    "mlp": (TinyMLP, ["fc1", "fc2"], lambda: torch.randn(6, 8)),
    "attention": (TinyAttention, ["q_proj", "k_proj", "v_proj", "out_proj"], None),
}
METHODS = {
    "lora": lambda m, t: apply_lora_to_model(m, t, rank=4, alpha=8),
    "oft": lambda m, t: apply_oft_to_model(m, t, rank=4),
    "bottleneck": lambda m, t: apply_adapter_to_model(m, t, bottleneck_dim=4),
}


def make(model_name: str, method: str | None = None):
    torch.manual_seed(0)
    cls, targets, _ = MODELS[model_name]
    model = cls()
    base = copy.deepcopy(model)
    if method is not None:
        METHODS[method](model, targets)
    return model, base


def inputs(model_name: str) -> torch.Tensor:
    g = torch.Generator().manual_seed(1)
    if model_name == "mlp":
        return torch.randn(6, 8, generator=g)
    return torch.randn(3, 5, 16, generator=g)


def train(model: nn.Module, x: torch.Tensor, steps: int = 8) -> None:
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=5e-2)
    target = torch.randn(x.shape[0], 4, generator=torch.Generator().manual_seed(2))
    for _ in range(steps):
        loss = (model(x) - target).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()


ALL = [(m, k) for m in MODELS for k in METHODS]


@pytest.mark.parametrize(("model_name", "method"), ALL)
def test_only_adapter_parameters_train(model_name, method):
    model, _ = make(model_name, method)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    adapter_keys = set(adapter_state_dict(model))
    trainable = {n for n, p in model.named_parameters() if p.requires_grad}
    assert trainable == adapter_keys and trainable
    count = trainable_parameters(model)
    assert count.trainable == sum(model.state_dict()[k].numel() for k in adapter_keys)
    assert 0 < count.fraction < 1
    train(model, inputs(model_name), steps=3)
    for key, value in model.state_dict().items():
        changed = not torch.equal(value, before[key])
        assert changed == (key in adapter_keys), key


@pytest.mark.parametrize(("model_name", "method"), ALL)
def test_identity_at_init_and_disable_restores_base(model_name, method):
    model, base = make(model_name, method)
    x = inputs(model_name)
    with torch.no_grad():
        torch.testing.assert_close(model(x), base(x), rtol=0, atol=0)  # exact at init
    train(model, x)
    with torch.no_grad():
        adapted = model(x)
        assert (adapted - base(x)).abs().max() > 1e-3  # training moved the output
        with adapters_disabled(model):
            torch.testing.assert_close(model(x), base(x), rtol=0, atol=0)
        torch.testing.assert_close(model(x), adapted, rtol=0, atol=0)


@pytest.mark.parametrize("model_name", list(MODELS))
@pytest.mark.parametrize("method", ["lora", "oft"])
def test_merged_equals_unmerged_and_is_plain(model_name, method):
    model, _ = make(model_name, method)
    x = inputs(model_name)
    train(model, x)
    with torch.no_grad():
        unmerged = model(x)
    merged = merge_peft(model)
    assert not any(isinstance(m, BaseTunerLayer) for m in merged.modules())
    assert {type(m) for m in merged.children()} <= {nn.Linear, nn.GELU}
    assert not hasattr(merged, "peft_config")
    with torch.no_grad():
        torch.testing.assert_close(merged(x), unmerged, rtol=0, atol=1e-5)
    fresh = MODELS[model_name][0]()
    assert set(merged.state_dict()) == set(fresh.state_dict())  # loads into a plain model


def test_lora_matches_closed_form():
    model, base = make("mlp", None)
    apply_lora_to_model(model, ["fc1"], rank=2, alpha=6)
    layer = model.fc1
    A = torch.randn(2, 8)
    B = torch.randn(16, 2)
    with torch.no_grad():
        layer.lora_A["default"].weight.copy_(A)
        layer.lora_B["default"].weight.copy_(B)
        x = torch.randn(4, 8)
        expected = base.fc1(x) + (6 / 2) * x @ A.T @ B.T  # W x + (alpha / r) B A x
        torch.testing.assert_close(layer(x), expected)


def test_bottleneck_is_kept_or_refused_by_merge():
    model, _ = make("mlp", "bottleneck")
    x = inputs("mlp")
    train(model, x)
    with torch.no_grad():
        before = model(x)
    with pytest.raises(ValueError, match="cannot be merged"):
        merge_peft(model, bottleneck="raise")
    merged = merge_peft(model, bottleneck="keep")
    assert isinstance(merged.fc1, BottleneckAdapter)
    with torch.no_grad():
        torch.testing.assert_close(merged(x), before, rtol=0, atol=0)


@pytest.mark.parametrize(("kwargs", "block"), [({"rank": 4}, 4), ({"block_size": 8}, 8)])
def test_oft_rotation_is_orthogonal_block_diagonal(kwargs, block):
    torch.manual_seed(0)
    model = nn.Sequential(nn.Linear(16, 8), nn.Tanh(), nn.Linear(8, 4))
    base = copy.deepcopy(model)
    apply_oft_to_model(model, ["0"], **kwargs)
    train(model, torch.randn(6, 16), steps=10)
    layer = model[0]
    assert layer.r["default"] * layer.oft_block_size["default"] == 16
    assert layer.oft_block_size["default"] == block
    R = oft_rotation(layer)  # (16, 16)
    torch.testing.assert_close(R.T @ R, torch.eye(16), rtol=0, atol=1e-5)
    assert (R - torch.eye(16)).abs().max() > 1e-2  # it actually rotates
    mask = torch.block_diag(*[torch.ones(block, block)] * (16 // block))
    assert R[mask == 0].abs().max() == 0  # block-diagonal
    x = torch.randn(5, 16)
    with torch.no_grad():
        torch.testing.assert_close(layer(x), base[0](x @ R), atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize(("model_name", "method"), ALL)
def test_adapter_weights_save_and_load_alone(model_name, method, tmp_path):
    model, base = make(model_name, method)
    x = inputs(model_name)
    train(model, x)
    path = save_adapter(model, tmp_path / "adapter.safetensors")
    saved = load_file(str(path))
    assert set(saved) == set(adapter_state_dict(model))
    assert sum(t.numel() for t in saved.values()) == trainable_parameters(model).trainable
    # A fresh copy of the base model: adapters are re-applied from the file's record.
    restored = load_adapter(copy.deepcopy(base), path)
    with torch.no_grad():
        torch.testing.assert_close(restored(x), model(x), rtol=0, atol=0)
    # Loading into a model with differently shaped adapters fails clearly.
    other = copy.deepcopy(base)
    if method == "lora":
        apply_lora_to_model(other, MODELS[model_name][1], rank=2, alpha=8)
    elif method == "oft":
        apply_oft_to_model(other, MODELS[model_name][1], rank=2)
    else:
        apply_adapter_to_model(other, MODELS[model_name][1], bottleneck_dim=2)
    with pytest.raises(ValueError, match="shape"):
        load_adapter(other, path)


def test_bad_arguments_raise_clearly():
    model, _ = make("mlp", None)
    with pytest.raises(ValueError, match="nope"):
        apply_lora_to_model(model, ["fc1", "nope"], rank=2, alpha=4)
    with pytest.raises(ValueError, match="GELU"):
        apply_lora_to_model(model, ["act"], rank=2, alpha=4)
    with pytest.raises(ValueError, match="target_modules"):
        apply_lora_to_model(model, [], rank=2, alpha=4)
    with pytest.raises(ValueError, match="rank"):
        apply_lora_to_model(model, ["fc1"], rank=0, alpha=4)
    with pytest.raises(ValueError, match="in_features=8"):
        apply_oft_to_model(model, ["fc1"], rank=3)
    with pytest.raises(ValueError, match="exactly one"):
        apply_oft_to_model(model, ["fc1"], rank=2, block_size=4)
    with pytest.raises(ValueError, match="MultiheadAttention"):
        apply_lora_to_model(nn.TransformerEncoderLayer(8, 2), ["out_proj"], rank=2, alpha=4)
    apply_lora_to_model(model, ["fc1"], rank=2, alpha=4)
    with pytest.raises(ValueError, match="already carries"):
        apply_adapter_to_model(model, ["fc1"])
    assert not any(isinstance(m, BaseTunerLayer) for m in model.fc2.modules())


def test_regex_and_all_linear_targets():
    model, _ = make("attention", None)
    apply_lora_to_model(model, r"[qv]_proj", rank=2, alpha=4)
    adapted = {n for n, m in model.named_modules() if isinstance(m, BaseTunerLayer)}
    assert adapted == {"q_proj", "v_proj"}
    model, _ = make("mlp", None)
    apply_adapter_to_model(model, "all-linear")
    assert all(isinstance(getattr(model, n), BottleneckAdapter) for n in ("fc1", "fc2", "head"))


def test_lora_on_the_dual_system_s1():
    from vla_gr.core.dual_system import DualSystemArchitecture

    torch.manual_seed(0)
    model = DualSystemArchitecture(16, 12, 32, 32, 2.0, 10.0, s2_num_heads=4).eval()
    vis, vlm, prop = torch.randn(2, 16), torch.randn(2, 12), torch.randn(2, 7)
    with torch.no_grad():
        ref = model(visual_features=vis, vlm_features=vlm, proprioception=prop)["action"]
    apply_lora_to_model(model.s1, "all-linear", rank=4, alpha=8)
    model.reset()
    with torch.no_grad():
        out = model(visual_features=vis, vlm_features=vlm, proprioception=prop)["action"]
    torch.testing.assert_close(out, ref, rtol=0, atol=0)
    assert trainable_parameters(model.s1).fraction < 0.2


def test_merge_peft_unwraps_a_peft_model():
    from peft import LoraConfig, get_peft_model

    model, _ = make("mlp", None)
    wrapped = get_peft_model(model, LoraConfig(r=2, lora_alpha=4, target_modules=["fc1"]))
    x = inputs("mlp")
    train(wrapped, x)
    with torch.no_grad():
        expected = wrapped(x)
    plain = merge_peft(wrapped)
    assert type(plain) is TinyMLP and isinstance(plain.fc1, nn.Linear)
    with torch.no_grad():
        torch.testing.assert_close(plain(x), expected, rtol=0, atol=1e-5)


@pytest.mark.parametrize("method", ["lora", "oft"])
def test_trajectory_encoder_adapters_are_live_and_merge_exactly(method):
    from vla_gr.core.trajectory_attention import TrajectoryEncoder

    torch.manual_seed(0)
    enc = TrajectoryEncoder(action_dim=3, hidden_dim=32, num_layers=2, num_action_queries=8).eval()
    base = copy.deepcopy(enc)
    ctx = torch.randn(2, 5, 32)  # (B, T, C)
    targets = ["q_proj", "k_proj", "v_proj", "out_proj"]
    if method == "lora":
        apply_lora_to_model(enc, targets, rank=4, alpha=8)
    else:
        apply_oft_to_model(enc, targets, rank=8)
    with torch.no_grad():
        torch.testing.assert_close(
            enc(context=ctx, num_actions=8), base(context=ctx, num_actions=8)
        )
        for p in enc.parameters():  # perturb every adapter weight
            if p.requires_grad:
                p.normal_(0.0, 0.1)
        adapted = enc(context=ctx, num_actions=8)  # (B, 8, 3)
        assert (adapted - base(context=ctx, num_actions=8)).abs().max() > 1e-3
        merged = merge_peft(enc)
        torch.testing.assert_close(merged(context=ctx, num_actions=8), adapted, rtol=0, atol=1e-5)


def test_mixed_lora_and_bottleneck_round_trip(tmp_path):
    model, base = make("mlp", None)
    apply_lora_to_model(model, ["fc1"], rank=2, alpha=4)
    apply_adapter_to_model(model, ["head"], bottleneck_dim=3)
    trainable = {n for n, p in model.named_parameters() if p.requires_grad}
    assert any("lora_" in n for n in trainable) and any("adapter_" in n for n in trainable)
    x = inputs("mlp")
    train(model, x)
    restored = load_adapter(copy.deepcopy(base), save_adapter(model, tmp_path / "a.safetensors"))
    with torch.no_grad():
        torch.testing.assert_close(restored(x), model(x), rtol=0, atol=0)
        merged = merge_peft(restored)
        torch.testing.assert_close(merged(x), model(x), rtol=0, atol=1e-5)
    assert isinstance(merged.fc1, nn.Linear) and isinstance(merged.head, BottleneckAdapter)
