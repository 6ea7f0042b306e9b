"""The perception engine seam: each network's ONNX Runtime export computes what PyTorch does
(any batch and image size), through the same pre- and post-processing."""

import pytest
import torch

from vla_gr.agent.perception import (
    GoalHead,
    GoalHeadConfig,
    ObjectCategoryConfig,
    ObjectCategorySegmenter,
    PerceptionConfig,
    RoomTypeClassifier,
    RoomTypeConfig,
)
from vla_gr.agent.perception.engine import (
    OnnxNetwork,
    export_network,
    not_loaded,
    weights_digest,
)
from vla_gr.errors import ConfigError

pytest.importorskip("onnx")

SAID = ["find the red chair", "the bed in the kitchen"]


def _random_weights(module: torch.nn.Module) -> torch.nn.Module:
    """Every weight random (FiLM starts at zero: the instruction would change nothing)."""
    torch.manual_seed(0)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(0.3 * torch.randn_like(p))
    return module.eval()


def _frames(B: int, side: int):
    g = torch.Generator().manual_seed(B * side)
    rgb = torch.randint(0, 256, (B, 3, side, side), dtype=torch.uint8, generator=g)
    depth = 6.0 * torch.rand(B, 1, side, side, generator=g)  # (B, 1, S, S) m
    return rgb, depth


def _networks():
    head = GoalHead(GoalHeadConfig(text_encoder="hashed", channels=[8, 16], stem_channels=8,
                                   category_head=True))  # fmt: skip
    room = RoomTypeClassifier(RoomTypeConfig(input_size=8, channels=[8, 16]))
    segmenter = ObjectCategorySegmenter(ObjectCategoryConfig(channels=[8, 16]))
    return {
        "goal_head": (_random_weights(head), ("x", "text")),
        "room_type": (_random_weights(room), ("x",)),
        "object_category": (_random_weights(segmenter), ("x",)),
    }


def _inputs(name, module, B, side):
    said = (SAID[:B],) if name == "goal_head" else ()
    return module.network_inputs(*_frames(B, side), *said)


@pytest.mark.parametrize("name", ["goal_head", "room_type", "object_category"])
def test_the_export_computes_the_network_at_any_batch_and_size(name):
    module, input_names = _networks()[name]
    run = OnnxNetwork(export_network(module, _inputs(name, module, 1, 16), input_names))
    for B, side in ((1, 16), (2, 16), (2, 32)):  # traced on (1, 16): the axes stay free
        inputs = _inputs(name, module, B, side)
        with torch.no_grad():
            expected = module.network(*inputs)
        got = run(*inputs)
        assert list(got) == list(expected)  # the same outputs, by name
        for key, value in expected.items():
            assert got[key].shape == value.shape and got[key].dtype == value.dtype
            torch.testing.assert_close(got[key], value, atol=1e-4, rtol=1e-4)


def test_probabilities_through_either_engine_are_the_same_post_processing():
    nets = _networks()
    head, names = nets["goal_head"]
    head.config.test_time_flip = True  # the mirrored batch is built before the network
    rgb, depth = _frames(2, 16)
    onnx = OnnxNetwork(export_network(head, head.network_inputs(rgb, depth, SAID), names))
    with torch.no_grad():
        ref = head.probabilities(rgb, depth, SAID)
    got = head.probabilities(rgb, depth, SAID, onnx)
    assert set(got) == {"pixel", "visible", "category"}
    for key in ref:
        torch.testing.assert_close(got[key], ref[key], atol=1e-5, rtol=1e-4)
    for name in ("room_type", "object_category"):
        module, names = nets[name]
        onnx = OnnxNetwork(export_network(module, module.network_inputs(rgb, depth), names))
        torch.testing.assert_close(
            module.probabilities(rgb, depth, onnx), module.probabilities(rgb, depth), atol=1e-5,
            rtol=1e-4,
        )  # fmt: skip


def test_the_digest_follows_the_weights():
    module, _ = _networks()["room_type"]
    before = weights_digest(module)
    assert weights_digest(module) == before
    with torch.no_grad():
        module.logits.bias[0] += 1e-6
    assert weights_digest(module) != before


def test_engine_choice_and_an_export_not_loaded_are_one_line():
    assert PerceptionConfig().engine == "torch"
    with pytest.raises(ValueError, match=r"model.perception.engine='tensorrt'.*'onnxruntime'"):
        PerceptionConfig(engine="tensorrt")
    with pytest.raises(ConfigError, match="none is loaded.*engine=torch"):
        not_loaded("goal_head")(torch.zeros(1))
