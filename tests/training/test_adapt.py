"""The adapt stage: the shipped goal head given LoRA / OFT layers (merged: the same outputs on
real frames) or fully fine-tuned, on frames of the held-out house style; the written agent
keeps every other tensor of its input, and its trainable share is the configured one."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from peft.tuners.tuners_utils import BaseTunerLayer
from torch import nn

from vla_gr.checkpoint import read_checkpoint
from vla_gr.cli import main
from vla_gr.configs import load_config
from vla_gr.configs.training_schema import AdaptStageConfig
from vla_gr.evaluation.harness import evaluate
from vla_gr.policy import VLAGRPolicy, load_policy
from vla_gr.train import train
from vla_gr.training.adapt import add_adapters, frame_windows, merged_difference
from vla_gr.training.agent_stage import build_agent_from
from vla_gr.training.pipeline import run_pipeline
from vla_gr.training.stages import Services

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """Expert episodes 2-4 of `train` in the held-out `loft` style at 32 px."""
    path = tmp_path_factory.mktemp("loft") / "store.zarr"
    args = ["collect", "--config-name", "config_debug", f"collect.output={path}",
            "collect.split=train", "collect.first_episode=2", "collect.num_episodes=3",
            "env.house_style=loft", "env.max_episode_steps=60"]  # fmt: skip
    assert main(args) == 0
    return path


def _frames(store: Path, n: int = 6) -> dict:
    """``n`` stored windows of the held-out episodes as one batch."""
    windows = frame_windows(store, "val", AdaptStageConfig(), seed=0)
    items = [windows[i] for i in range(0, len(windows), max(1, len(windows) // n))][:n]
    return torch.utils.data.default_collate(items)


def _shipped() -> VLAGRPolicy:
    policy, _, _ = build_agent_from(SHIPPED, "goal_head", [], keep_part=True, forced=[])
    return policy.eval()


def _expected_lora(head: nn.Module, targets: list[str], rank: int) -> int:
    """LoRA parameters of rank ``rank`` on the Conv2d layers ``targets`` name: A (r, in, k, k)
    and B (out, r, 1, 1) per layer."""
    total = 0
    for name, m in head.named_modules():
        if isinstance(m, nn.Conv2d) and name.rsplit(".", 1)[-1] in targets:
            total += rank * (m.in_channels * m.kernel_size[0] * m.kernel_size[1] + m.out_channels)
    return total


@pytest.mark.parametrize(
    "method, targets, adapter", [("lora", ["conv1", "conv2"], "lora_B"), ("oft", ["film"], "oft_R")]
)
def test_merged_goal_head_equals_unmerged_on_real_frames(store, method, targets, adapter):
    policy = _shipped()
    batch = _frames(store)
    with torch.no_grad():
        base = policy.goal_outputs(batch)["pixel_logits"]  # (B, H, W)
    add_adapters(policy, AdaptStageConfig(method=method, targets=targets, rank=4))
    torch.manual_seed(1)
    with torch.no_grad():  # trained-looking adapters: away from their identity start
        for name, p in policy.goal_head.named_parameters():
            if adapter in name:
                p.add_(0.05 * torch.randn_like(p))
        unmerged = policy.goal_outputs(batch)["pixel_logits"]
    assert (unmerged - base).abs().max() > 1e-2  # the adapters change the outputs
    diff = merged_difference(policy, batch)  # merges in place, checked
    assert diff <= 1e-4
    assert not any(isinstance(m, BaseTunerLayer) for m in policy.modules())
    with torch.no_grad():
        merged = policy.goal_outputs(batch)["pixel_logits"]
    torch.testing.assert_close(merged, unmerged, atol=1e-4, rtol=0)
    assert set(policy.state_dict()) == set(_shipped().state_dict())  # plain keys again


def test_trainable_share_is_what_the_config_says():
    policy = _shipped()
    head = policy.goal_head
    base = sum(p.numel() for p in head.parameters())
    expected = _expected_lora(head, ["conv1", "conv2"], 8)
    counts = add_adapters(policy, AdaptStageConfig(method="lora", rank=8))
    assert counts["trainable_parameters"] == expected > 0
    assert counts["share_of_goal_head"] == pytest.approx(expected / base)
    trainable = [n for n, p in policy.named_parameters() if p.requires_grad]
    assert trainable and all("lora_" in n for n in trainable)  # only the adapters train
    full = add_adapters(_shipped(), AdaptStageConfig(method="full"))
    assert full["trainable_parameters"] == full["goal_head_parameters"] == base


def _adapt_pipeline(tmp: Path, store: Path, method: str) -> dict:
    stages = (
        f"pipeline.stages=[{{name:shipped,kind:source,path:'{SHIPPED}'}},"
        f"{{name:loft,kind:source,path:'{store}'}},"
        f"{{name:{method},kind:adapt,inputs:[shipped,loft]}}]"
    )
    resolved, cfg = load_config(
        "config_debug",
        [f"pipeline.output_dir={tmp}", stages, f"training.adapt.method={method}",
         "training.adapt.steps=2", "training.adapt.batch_size=4", "training.adapt.val_ratio=0.3",
         "training.device=cpu"],
    )  # fmt: skip
    return run_pipeline(resolved, cfg, Services(train=train, evaluate=evaluate))[method]


@pytest.mark.parametrize("method", ["lora", "full"])
def test_adapt_stage_writes_a_loadable_agent_with_the_other_tensors_unchanged(
    store, tmp_path, method
):
    record = _adapt_pipeline(tmp_path, store, method)
    out = Path(record["product"])
    assert type(load_policy(out)) is VLAGRPolicy
    given, written = read_checkpoint(SHIPPED), read_checkpoint(out)
    assert set(written.model) == set(given.model)  # merged: no adapter keys
    changed = {k for k in given.model if not torch.equal(given.model[k], written.model[k])}
    if method == "lora":  # the targeted convolutions' kernels (their biases stay)
        allowed = {k for k in given.model if k.startswith("goal_head.")}
        allowed = {k for k in allowed if k.endswith(("conv1.weight", "conv2.weight"))}
    else:
        allowed = {k for k in given.model if k.startswith("goal_head.")}
    assert changed and changed <= allowed
    summary = written.state["goal_head_adaptation"]
    assert summary["method"] == method and summary["steps"] == 2
    assert 0 < summary["share_of_goal_head"] <= 1.0
    assert (summary["merge_max_abs_diff"] is None) == (method == "full")
    assert {"held_out_before", "held_out_after", "seconds"} <= set(summary)
