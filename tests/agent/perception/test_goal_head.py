"""Goal head: shapes, conditioning on the instruction, losses and metrics against hand counts."""

import math

import pytest
import torch
import torch.nn.functional as F

from vla_gr.agent.perception import (
    GoalHead,
    GoalHeadConfig,
    confusion_metrics,
    goal_head_loss,
    mask_confusion,
    visible_targets,
)
from vla_gr.agent.perception.goal_head import upsample_nearest_2x


def _head(**kw) -> GoalHead:
    torch.manual_seed(0)
    return GoalHead(GoalHeadConfig(text_encoder="hashed", channels=[8, 16], stem_channels=8, **kw))


def _frames(B=2, side=16):
    g = torch.Generator().manual_seed(1)
    rgb = torch.randint(0, 256, (B, 3, side, side), dtype=torch.uint8, generator=g)
    depth = torch.rand(B, 1, side, side, generator=g) * 5.0
    return rgb, depth


def test_shapes_and_probabilities():
    head = _head()
    rgb, depth = _frames()
    out = head(rgb, depth, ["find the red chair", "go to the bed"])
    assert out["pixel_logits"].shape == (2, 16, 16)
    assert out["visible_logits"].shape == (2,)
    p, v = head.likelihood(rgb, depth, ["find the red chair", "go to the bed"])
    assert ((p >= 0) & (p <= 1)).all() and ((v >= 0) & (v <= 1)).all()


def test_learns_to_follow_the_instruction():
    # FiLM starts at identity (zero-init), so two instructions give the same map at first;
    # trained on the SAME frame with opposite targets per instruction, the map must follow
    # the instruction (only the text path can tell them apart).
    head = _head()
    rgb, depth = _frames(B=1)
    a, b = "find the red chair", "find the blue sofa"
    same = head(rgb, depth, [a])["pixel_logits"] - head(rgb, depth, [b])["pixel_logits"]
    assert same.abs().max() == 0
    top = torch.zeros(1, 16, 16, dtype=torch.bool)
    top[:, :8] = True
    opt = torch.optim.Adam(head.parameters(), lr=1e-2)
    for _ in range(40):
        out = head(rgb.repeat(2, 1, 1, 1), depth.repeat(2, 1, 1, 1), [a, b])
        loss = goal_head_loss(out["pixel_logits"], out["visible_logits"], torch.cat([top, ~top]))
        opt.zero_grad()
        loss["loss"].backward()
        opt.step()
    p_a, _ = head.likelihood(rgb, depth, [a])  # (1, 16, 16)
    p_b, _ = head.likelihood(rgb, depth, [b])
    assert p_a[0, :8].mean() > 0.8 and p_a[0, 8:].mean() < 0.2
    assert p_b[0, 8:].mean() > 0.8 and p_b[0, :8].mean() < 0.2


def test_bad_inputs_are_named():
    head = _head()
    rgb, depth = _frames(B=1)
    with pytest.raises(TypeError, match="sequence of str"):
        head(rgb, depth, [None])
    with pytest.raises(ValueError, match="divisible"):
        head(rgb[..., :15, :15], depth[..., :15, :15], ["x"])
    with pytest.raises(ValueError, match="1 instructions for 2 frames"):
        head(*_frames(B=2), ["x"])
    with pytest.raises(ValueError, match="model.goal_head.text_encoder"):
        GoalHeadConfig(text_encoder="clip")


def test_visible_targets_threshold():
    t = torch.zeros(3, 4, 4, dtype=torch.bool)
    t[1, 0, :3] = True  # 3 pixels
    t[2, :2, :2] = True  # 4 pixels
    assert visible_targets(t, min_pixels=4).tolist() == [0.0, 0.0, 1.0]


def test_loss_matches_hand_computation():
    logits = torch.tensor([[[0.0, 2.0], [-1.0, 0.5]]])  # (1, 2, 2)
    target = torch.tensor([[[True, False], [False, False]]])
    vis = torch.tensor([0.3])
    out = goal_head_loss(logits, vis, target, min_pixels=1, pos_weight=3.0, dice_weight=1.0,
                         visible_weight=0.5)  # fmt: skip
    sp = lambda x: math.log1p(math.exp(x))  # noqa: E731  softplus
    bce = (3.0 * sp(-0.0) + sp(2.0) + sp(-1.0) + sp(0.5)) / 4.0
    p = torch.sigmoid(logits).flatten().tolist()
    dice = 1.0 - (2.0 * p[0] + 1.0) / (sum(p) + 1.0 + 1.0)
    vbce = sp(-0.3)  # target visible (1 pixel >= min_pixels)
    assert out["pixel_bce"].item() == pytest.approx(bce, rel=1e-6)
    assert out["dice"].item() == pytest.approx(dice, rel=1e-6)
    assert out["visible_bce"].item() == pytest.approx(vbce, rel=1e-6)
    assert out["loss"].item() == pytest.approx(bce + dice + 0.5 * vbce, rel=1e-6)


def test_dice_ignores_frames_without_goal():
    logits = torch.full((2, 2, 2), 3.0)
    target = torch.zeros(2, 2, 2, dtype=torch.bool)
    assert goal_head_loss(logits, torch.zeros(2), target)["dice"].item() == 0.0


def test_confusion_counts_and_metrics():
    prob = torch.tensor([[[0.9, 0.6], [0.2, 0.4]], [[0.1, 0.1], [0.1, 0.7]]])  # (2, 2, 2)
    target = torch.tensor([[[True, False], [True, False]], [[False, False], [False, False]]])
    counts = mask_confusion(prob, torch.tensor([0.8, 0.6]), target, min_pixels=2)
    assert counts == {"tp": 1, "fp": 2, "fn": 1, "frames": 2, "frames_correct": 1,
                      "frames_visible": 1}  # fmt: skip
    m = confusion_metrics(counts)
    assert m["pixel_precision"] == pytest.approx(1 / 3)
    assert m["pixel_recall"] == pytest.approx(1 / 2)
    assert m["pixel_iou"] == pytest.approx(1 / 4)
    assert m["visible_accuracy"] == pytest.approx(1 / 2)
    empty = confusion_metrics(dict(counts, tp=0, fp=0))
    assert math.isnan(empty["pixel_precision"])


def test_distractor_share_of_predicted_pixels():
    prob = torch.tensor([[[0.9, 0.6], [0.7, 0.4]], [[0.8, 0.1], [0.1, 0.1]]])  # (2, 2, 2)
    target = torch.tensor([[[True, False], [False, False]], [[False, False], [False, False]]])
    others = torch.tensor([[[False, True], [False, True]], [[True, False], [False, False]]])
    counts = mask_confusion(prob, torch.tensor([0.8, 0.2]), target, distractors=others)
    # predicted: (0,0,0) goal, (0,0,1) distractor, (0,1,0) floor, (1,0,0) distractor;
    # (0,1,1) is a distractor pixel below the threshold
    assert counts["fp_distractor"] == 2 and counts["tp"] == 1 and counts["fp"] == 3
    assert confusion_metrics(counts)["on_distractor"] == pytest.approx(2 / 4)
    assert math.isnan(
        confusion_metrics(mask_confusion(prob, torch.zeros(2), target))["on_distractor"]
    )
    nothing = mask_confusion(torch.zeros(2, 2, 2), torch.zeros(2), target, distractors=others)
    assert nothing["fp_distractor"] == 0 and math.isnan(confusion_metrics(nothing)["on_distractor"])


def test_loss_and_metric_defaults_are_the_configs():
    import inspect

    from vla_gr.agent.perception import GroundingConfig

    c = GroundingConfig()
    loss = inspect.signature(goal_head_loss).parameters
    conf = inspect.signature(mask_confusion).parameters
    for key in ("min_pixels", "pos_weight", "dice_weight", "visible_weight", "category_weight"):
        assert loss[key].default == getattr(c, key)
    assert (conf["threshold"].default, conf["min_pixels"].default) == (c.threshold, c.min_pixels)
    with pytest.raises(ValueError, match="model.grounding.threshold"):
        GroundingConfig(threshold=1.0)


def test_category_output_gates_the_instance_probability():
    head = _head(category_head=True)
    rgb, depth = _frames()
    instructions = ["find the red chair", "go to the bed"]
    out = head(rgb, depth, instructions)
    assert out["category_logits"].shape == (2, 16, 16)
    p, v = head.likelihood(rgb, depth, instructions)
    expected = torch.sigmoid(out["pixel_logits"]) * torch.sigmoid(out["category_logits"])
    torch.testing.assert_close(p, expected)
    torch.testing.assert_close(v, torch.sigmoid(out["visible_logits"]))
    # a pixel the category output rules out is not the goal, however sure the instance output is
    sure = {"pixel_logits": torch.full((1, 2, 2), 20.0),
            "category_logits": torch.tensor([[[20.0, -20.0], [20.0, -20.0]]])}  # fmt: skip
    gated = head.pixel_probability(sure)
    assert (gated[0, :, 0] > 0.99).all() and (gated[0, :, 1] < 1e-6).all()
    # the ablation switch: the instance output alone
    ungated = _head(category_head=True, category_gate=False)
    assert (ungated.pixel_probability(sure) > 0.99).all()
    with pytest.raises(ValueError, match="category_gate=false"):
        GoalHeadConfig(category_gate=False)  # no category output to switch off
    # without the category output the probability is the instance output's alone
    plain = _head()
    assert "category_logits" not in plain(rgb, depth, instructions)
    p0, _ = plain.likelihood(rgb, depth, instructions)
    torch.testing.assert_close(p0, torch.sigmoid(plain(rgb, depth, instructions)["pixel_logits"]))


def test_category_loss_is_the_weighted_mask_terms_on_goal_or_distractors():
    logits = torch.tensor([[[0.0, 2.0], [-1.0, 0.5]]])  # (1, 2, 2)
    category = torch.tensor([[[1.0, -2.0], [0.5, 0.0]]])
    goal = torch.tensor([[[True, False], [False, False]]])
    same_category = torch.tensor([[[True, False], [True, False]]])  # goal + one distractor
    vis = torch.tensor([0.3])
    base = goal_head_loss(logits, vis, goal, pos_weight=3.0)
    out = goal_head_loss(logits, vis, goal, pos_weight=3.0, category_logits=category,
                         category_target=same_category, category_weight=0.5)  # fmt: skip
    sp = lambda x: math.log1p(math.exp(x))  # noqa: E731  softplus
    bce = (3.0 * sp(-1.0) + sp(-2.0) + 3.0 * sp(-0.5) + sp(0.0)) / 4.0
    p = torch.sigmoid(category).flatten().tolist()
    dice = 1.0 - (2.0 * (p[0] + p[2]) + 1.0) / (sum(p) + 2.0 + 1.0)
    assert out["category_bce"].item() == pytest.approx(bce, rel=1e-6)
    assert out["category_dice"].item() == pytest.approx(dice, rel=1e-6)
    assert out["loss"].item() == pytest.approx(base["loss"].item() + 0.5 * (bce + dice), rel=1e-6)
    for key in ("pixel_bce", "dice", "visible_bce"):
        assert out[key].item() == base[key].item()
    with pytest.raises(ValueError, match="cover the goal"):
        goal_head_loss(logits, vis, goal, category_logits=category, category_target=~goal)
    with pytest.raises(ValueError, match="go together"):
        goal_head_loss(logits, vis, goal, category_logits=category)


def test_test_time_flip_averages_the_mirror_and_is_mirror_equivariant():
    plain, flip = _head(category_head=True), _head(category_head=True, test_time_flip=True)
    rgb, depth = _frames()
    instructions = ["find the red chair", "go to the bed"]
    p, v = plain.likelihood(rgb, depth, instructions)
    pm, vm = plain.likelihood(rgb.flip(-1), depth.flip(-1), instructions)
    p2, v2 = flip.likelihood(rgb, depth, instructions)
    torch.testing.assert_close(p2, 0.5 * (p + pm.flip(-1)))
    torch.testing.assert_close(v2, 0.5 * (v + vm))
    assert not torch.allclose(p2, p)  # the mirror pass changed something
    # the averaged map of a mirrored frame is the mirrored map, exactly what one pass is not
    q2, w2 = flip.likelihood(rgb.flip(-1), depth.flip(-1), instructions)
    torch.testing.assert_close(q2, p2.flip(-1))
    torch.testing.assert_close(w2, v2)
    assert not torch.allclose(pm, p.flip(-1))


def test_decoder_upsampling_repeats_each_value_into_a_2x2_block():
    torch.manual_seed(0)
    h = torch.randn(2, 5, 3, 4)
    up = upsample_nearest_2x(h)  # (2, 5, 6, 8)
    assert up.shape == (2, 5, 6, 8)
    assert torch.equal(up, F.interpolate(h, scale_factor=2, mode="nearest"))
    for dr in (0, 1):
        for dc in (0, 1):
            assert torch.equal(up[:, :, dr::2, dc::2], h)


def _stage_calls_and_gradients(on: bool) -> tuple[GoalHead, list[int], dict]:
    """A seeded head with checkpointing ``on``: (it, the calls of its first down stage,
    the gradients of one backward)."""
    rgb, depth = _frames()
    head = _head()
    head.gradient_checkpointing = on
    calls = [0]
    head.down[0].register_forward_pre_hook(lambda *_: calls.__setitem__(0, calls[0] + 1))
    out = head(rgb, depth, ["find the red chair", "go to the bed"])
    (out["pixel_logits"].square().mean() + out["visible_logits"].sum()).backward()
    return head, calls, {n: p.grad for n, p in head.named_parameters() if p.grad is not None}


def test_gradient_checkpointing_recomputes_each_stage_with_the_same_gradients():
    _, plain_calls, plain = _stage_calls_and_gradients(False)
    head, calls, grads = _stage_calls_and_gradients(True)
    assert (plain_calls[0], calls[0]) == (1, 2)  # checkpointed: the stage runs again in backward
    assert grads.keys() == plain.keys()
    for name, grad in plain.items():
        torch.testing.assert_close(grads[name], grad, msg=name)
    calls[0] = 0
    with torch.no_grad():  # inference never recomputes
        head.eval()(*_frames(), ["find the red chair", "go to the bed"])
    assert calls[0] == 1
