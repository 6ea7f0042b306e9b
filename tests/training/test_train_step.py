"""train_step: accumulation equals one big batch; AMP; optimiser / schedule / EMA maths."""

from __future__ import annotations

import copy
import math

import pytest
import torch

from tests.helpers import fake_batch, split_batch, tiny_model_config, tiny_policy
from vla_gr.training.ema import EMA, ema_decay
from vla_gr.training.optim import CPUOffloadAdamW, build_optimizer, param_groups, warmup_cosine
from vla_gr.training.step import train_step


def _step(model, micro, **kw):
    opt = build_optimizer(model, lr=1e-3, weight_decay=0.1)
    return train_step(model, micro, opt, grad_clip=1.0, **kw)


def _sgd_step(model, micro):
    # SGD makes the update proportional to the gradient. (Adam divides by |g|, which turns
    # float rounding noise on parameters whose true gradient is 0 -- attention key biases
    # -- into full-size steps of random sign; that is not what this test is about.)
    opt = torch.optim.SGD(model.parameters(), lr=0.5)
    return train_step(model, micro, opt, grad_clip=0.0)


def test_accumulation_4x2_equals_one_batch_of_8():
    cfg = tiny_model_config()
    batch = fake_batch(cfg, 8, seed=1)
    a = tiny_policy(0)
    b = copy.deepcopy(a)
    out_a = _sgd_step(a, [batch])
    out_b = _sgd_step(b, split_batch(batch, 4))
    assert out_a["loss"] == pytest.approx(out_b["loss"], abs=1e-6)
    assert out_a["grad_norm"] == pytest.approx(out_b["grad_norm"], rel=1e-5)
    moved = 0.0
    ref = tiny_policy(0).state_dict()
    for (name, pa), pb in zip(a.state_dict().items(), b.state_dict().values()):
        torch.testing.assert_close(pa, pb, atol=1e-6, rtol=0, msg=name)
        moved = max(moved, (pa - ref[name]).abs().max().item())
    assert moved > 1e-4  # the step did update the weights


def test_accumulation_differs_from_unscaled_sum():
    """Guard against the classic bug: summing micro-batch losses without dividing by K."""
    cfg = tiny_model_config()
    batch = fake_batch(cfg, 8, seed=2)
    model = tiny_policy(0)
    model.zero_grad()
    model(batch)["loss"].backward()
    g_full = torch.cat([p.grad.flatten() for p in model.parameters() if p.grad is not None])
    out = _step(copy.deepcopy(model), split_batch(batch, 4), device="cpu")
    assert out["grad_norm"] == pytest.approx(g_full.norm().item(), rel=1e-5)


def test_bf16_autocast_runs_on_cpu_and_learns():
    cfg = tiny_model_config(objective="flow_matching", sampler="euler")
    batch = fake_batch(cfg, 4, seed=3)
    model = tiny_policy(0, objective="flow_matching", sampler="euler")
    before = copy.deepcopy(model.state_dict())
    out = _step(model, [batch], amp="bf16")
    assert math.isfinite(out["loss"]) and math.isfinite(out["grad_norm"])
    changed = [k for k, v in model.state_dict().items() if not torch.equal(v, before[k])]
    assert changed, "bf16 step left every weight unchanged"
    assert all(v.dtype == torch.float32 for v in model.state_dict().values())


def test_fp16_gradscaler_step_on_cpu():
    cfg = tiny_model_config()
    model = tiny_policy(0)
    opt = build_optimizer(model, lr=1e-3, weight_decay=0.0)
    scaler = torch.amp.GradScaler("cpu", init_scale=2.0**8)
    out = train_step(model, [fake_batch(cfg, 4)], opt, scaler=scaler, amp="fp16")
    assert math.isfinite(out["loss"])
    assert scaler.get_scale() in (2.0**8, 2.0**7)  # unchanged, or halved after an overflow


def test_weight_decay_only_on_matrices():
    model = tiny_policy(0)
    decay, no_decay = param_groups(model, 0.1)
    assert decay["weight_decay"] == 0.1 and no_decay["weight_decay"] == 0.0
    assert all(p.dim() >= 2 for p in decay["params"])
    assert all(p.dim() < 2 for p in no_decay["params"])
    n = sum(1 for p in model.parameters() if p.requires_grad)
    assert len(decay["params"]) + len(no_decay["params"]) == n


def test_warmup_cosine_values():
    f = lambda s: warmup_cosine(s, warmup_steps=10, total_steps=110, min_ratio=0.1)  # noqa: E731
    assert f(0) == pytest.approx(0.1) and f(9) == pytest.approx(1.0)
    assert f(10) == pytest.approx(1.0)
    assert f(60) == pytest.approx(0.1 + 0.9 * 0.5)  # half-way through the cosine
    assert f(110) == pytest.approx(0.1) and f(500) == pytest.approx(0.1)


def test_ema_matches_hand_computed_average():
    assert ema_decay(0, 0.99) == pytest.approx(0.1)
    assert ema_decay(10**6, 0.99) == 0.99 and ema_decay(0, 0.9, warmup=False) == 0.9
    lin = torch.nn.Linear(2, 1, bias=False)
    with torch.no_grad():
        lin.weight.fill_(1.0)
    ema = EMA(lin, decay=0.5, warmup=False)
    for value in (3.0, 5.0):
        with torch.no_grad():
            lin.weight.fill_(value)
        ema.update(lin)
    # 0.5 * (0.5 * 1 + 0.5 * 3) + 0.5 * 5 = 3.5
    assert torch.allclose(ema.shadow["weight"], torch.full((1, 2), 3.5))
    with ema.average_parameters(lin):
        assert torch.allclose(lin.weight, torch.full((1, 2), 3.5))
    assert torch.allclose(lin.weight, torch.full((1, 2), 5.0))  # restored


def test_cpu_offload_adamw_matches_adamw_and_round_trips():
    cfg = tiny_model_config()
    a = tiny_policy(0)
    b = copy.deepcopy(a)
    opt_a = build_optimizer(a, lr=1e-2, weight_decay=0.1, fused=False)
    opt_b = CPUOffloadAdamW(b, lr=1e-2, weight_decay=0.1)
    for seed in range(3):
        batch = [fake_batch(cfg, 4, seed=seed)]
        train_step(a, batch, opt_a, grad_clip=1.0)
        train_step(b, batch, opt_b, grad_clip=1.0)
    for (name, pa), pb in zip(a.named_parameters(), b.parameters()):
        torch.testing.assert_close(pa, pb, atol=1e-6, rtol=0, msg=name)
    fresh = CPUOffloadAdamW(b, lr=1.0, weight_decay=0.0)
    fresh.load_state_dict(opt_b.state_dict())
    assert fresh.param_groups[0]["lr"] == pytest.approx(1e-2)


def test_peft_lora_trains_only_adapters():
    from vla_gr.configs.model_schema import PeftConfig
    from vla_gr.policy import apply_peft

    model = apply_peft(tiny_policy(0), PeftConfig(enabled=True, method="lora", lora_rank=2))
    trainable = [n for n, p in model.named_parameters() if p.requires_grad]
    assert trainable and all("lora_" in n for n in trainable)
    frozen = {n: p.detach().clone() for n, p in model.named_parameters() if not p.requires_grad}
    out = _step(model, [fake_batch(tiny_model_config(), 4)])
    assert math.isfinite(out["loss"])
    for n, p in model.named_parameters():
        if n in frozen:
            assert torch.equal(p, frozen[n]), n
