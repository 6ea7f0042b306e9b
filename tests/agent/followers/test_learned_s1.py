"""The learned S1: its size, loss and gradients, sampling, and the follower's schedule, STOP
decision and determinism."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import torch

from vla_gr.agent.followers import LearnedFollower, PursuitConfig, S1Policy
from vla_gr.agent.followers.pure_pursuit import clearance_ahead, guarded_speed
from vla_gr.agent.followers.s1_inputs import plan_vector_size
from vla_gr.agent.navigator.navigator import NavPlan
from vla_gr.core.diffusion_policy import HeadConfig
from vla_gr.core.dual_system import S1Config
from vla_gr.core.dual_system.config import _s1_head


def tiny_s1(**kw) -> S1Config:
    """A ~20 k-parameter S1 on 16x16 inputs."""
    head = HeadConfig(action_dim=2, hidden_dim=16, objective="flow_matching", horizon=4,
                      num_inference_steps=2, down_dims=[16, 32], n_groups=4)  # fmt: skip
    args = dict(kind="learned", image_size=16, channels=[8, 16], dim=32, head=head)
    args.update(kw)
    return S1Config(**args)


def _batch(config: S1Config, b: int = 3, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    s, h = config.image_size, config.head.horizon
    return {
        "rgb": torch.randint(0, 256, (b, 3, s, s), generator=g, dtype=torch.uint8),
        "depth": torch.rand(b, 1, s, s, generator=g) * 8.0,
        "plan": torch.randn(b, plan_vector_size(config.path_points), generator=g),
        "chunk": torch.rand(b, h, 2, generator=g) * 2 - 1,
        "stop": torch.tensor([1.0, 0.0, 0.0][:b]),
    }


HEADS = {
    "flow_matching": {},
    "diffusion_ddim": dict(objective="diffusion", sampler="ddim"),
    "l1": dict(objective="l1"),
    "transformer": dict(denoiser="transformer"),
}


@pytest.mark.parametrize("head", HEADS)
def test_default_s1_stays_under_two_million_parameters_with_every_head(head):
    config = S1Config(head=dataclasses.replace(_s1_head(), **HEADS[head]))
    torch.manual_seed(0)
    policy = S1Policy(config)
    assert sum(p.numel() for p in policy.parameters()) <= 2_000_000
    assert policy.head.context_dim == config.dim  # the head reads S1's tokens
    batch = _batch(config)
    loss = policy(batch)["loss"]
    assert torch.isfinite(loss)
    chunk, stop = policy.act(batch["rgb"], batch["depth"], batch["plan"])
    assert chunk.shape == (3, config.head.horizon, 2) and stop.shape == (3,)


@pytest.mark.parametrize("head", HEADS)
def test_loss_reaches_every_part_and_act_is_bounded(head):
    config = tiny_s1(head=dataclasses.replace(tiny_s1().head, **HEADS[head]))
    torch.manual_seed(0)
    policy = S1Policy(config)
    batch = _batch(config)
    out = policy(batch)
    assert set(out) == {"loss", "action_loss", "stop_loss", "stop_acc"}
    assert all(torch.isfinite(v) for v in out.values())
    torch.testing.assert_close(
        out["loss"], out["action_loss"] + config.stop_weight * out["stop_loss"]
    )
    out["loss"].backward()
    parts = {
        "encoder": policy.encoder[0].weight,
        "visual_proj": policy.visual_proj.weight,
        "plan MLP": policy.plan_proj[0].weight,
        "fuse": policy.fuse[1].weight,
        "stop head": policy.stop_head[2].weight,
    }
    for name, weight in parts.items():
        assert weight.grad is not None and weight.grad.abs().sum() > 0, name
    head_grads = [p.grad for p in policy.head.parameters() if p.grad is not None]
    assert head_grads and sum(g.abs().sum() for g in head_grads) > 0

    chunk, stop = policy.act(batch["rgb"], batch["depth"] * 100.0, batch["plan"] * 50.0)
    assert chunk.shape == (3, config.head.horizon, 2)
    assert chunk.abs().max() <= 1.0 and ((stop >= 0.0) & (stop <= 1.0)).all()


def test_stop_loss_is_the_bce_of_the_stop_logit():
    config = tiny_s1(stop_weight=0.5)
    torch.manual_seed(0)
    policy = S1Policy(config)
    batch = _batch(config)
    _, logit = policy.encode(batch["rgb"], batch["depth"], batch["plan"])
    p = torch.sigmoid(logit)
    bce = -(batch["stop"] * p.log() + (1 - batch["stop"]) * (1 - p).log()).mean()
    out = policy(batch)
    torch.testing.assert_close(out["stop_loss"], bce)
    acc = ((p > config.stop_threshold).float() == batch["stop"]).float().mean()
    torch.testing.assert_close(out["stop_acc"], acc)
    # a confident, right STOP costs nothing
    with torch.no_grad():
        policy.stop_head[2].bias.fill_(30.0)
    assert policy(dict(batch, stop=torch.ones(3)))["stop_loss"] < 1e-6


# --------------------------------------------------------------------------- the follower


def _frames(n: int, seed: int = 0):
    """n observations (rgb (32, 32, 3), depth (32, 32, 1), pose (3,)), a robot driving ahead."""
    rng = np.random.default_rng(seed)
    for t in range(n):
        rgb = rng.integers(0, 256, (32, 32, 3)).astype(np.uint8)
        depth = rng.uniform(0.3, 9.0, (32, 32, 1)).astype(np.float32)
        yield rgb, depth, np.array([0.1 * t, 0.02 * t, 0.05 * t])


def _plan(mode="approach") -> NavPlan:
    return NavPlan(np.array([[1.0, 0.0], [2.0, 1.0]]), mode, 0.5, False, goal_distance=2.0)


class CountingPolicy:
    """Wraps ``S1Policy.act``: counts the calls and keeps what S1 read and returned."""

    def __init__(self, policy: S1Policy) -> None:
        self.calls: list[dict] = []
        self.act = policy.act

        def act(rgb, depth, plan, generator=None):
            chunk, stop = self.act(rgb, depth, plan, generator)
            self.calls.append({"plan": plan[0].numpy().copy(), "chunk": chunk[0].numpy()})
            return chunk, stop

        policy.act = act


def _follower(seed: int = 0, weights_seed: int = 0, **kw) -> LearnedFollower:
    torch.manual_seed(weights_seed)
    return LearnedFollower(S1Policy(tiny_s1(**kw)), seed=seed)


def _drive(follower: LearnedFollower, n: int, plan_at=(0,)) -> np.ndarray:
    actions = []
    for t, (rgb, depth, pose) in enumerate(_frames(n)):
        if t in plan_at:
            follower.set_plan(_plan(), pose)
        actions.append(follower.act(depth, pose, rgb=rgb))
    return np.stack(actions)  # (n, 3)


def test_same_weights_and_seed_give_the_same_actions_after_reset():
    a, b = _follower(seed=3), _follower(seed=3)
    b.policy.load_state_dict(copy.deepcopy(a.policy.state_dict()))
    first = _drive(a, 9)
    assert first.shape == (9, 3) and first.dtype == np.float32
    # interleaved with unrelated draws from the global RNG: only the follower's seed counts
    torch.manual_seed(123)
    torch.randn(100)
    second = _drive(b, 9)
    np.testing.assert_array_equal(first, second)
    a.reset()  # a new episode replays the same noise
    np.testing.assert_array_equal(_drive(a, 9), first)
    c = _follower(seed=4)
    c.policy.load_state_dict(a.policy.state_dict())
    assert not np.array_equal(_drive(c, 9), first)  # the seed does drive the sampler


def test_executes_n_action_steps_per_s1_call_and_a_new_plan_decides_at_once():
    follower = _follower(n_action_steps=3)
    counter = CountingPolicy(follower.policy)
    with torch.no_grad():
        follower.policy.stop_head[2].bias.fill_(-50.0)  # never STOP
    actions = _drive(follower, 7)
    assert len(counter.calls) == 3  # steps 0, 3, 6
    for k, call in enumerate(counter.calls):  # each call's first 3 (v, w) are executed in order
        executed = actions[3 * k : 3 * k + 3]
        np.testing.assert_allclose(executed[:, :2], call["chunk"][: len(executed)], atol=0)
        assert (executed[:, 2] == -1.0).all()

    follower.reset()
    counter.calls.clear()
    _drive(follower, 6, plan_at=(0, 1, 4))  # new plans mid-chunk
    assert len(counter.calls) == 3  # steps 0, 1 (new plan), 4 (new plan)
    assert [c["plan"][-1] for c in counter.calls] == [0.0, 0.0, 0.0]  # each from a fresh plan


def test_stop_head_decides_stop():
    follower = _follower(n_action_steps=2)
    counter = CountingPolicy(follower.policy)
    with torch.no_grad():
        follower.policy.stop_head[2].bias.fill_(50.0)
    actions = _drive(follower, 5)
    np.testing.assert_array_equal(actions, np.tile([0.0, 0.0, 1.0], (5, 1)))
    assert len(counter.calls) == 5  # a STOP queues nothing: S1 decides again next step
    assert follower.last_stop_probability == pytest.approx(1.0)

    follower.reset()
    with torch.no_grad():
        follower.policy.stop_head[2].bias.fill_(-50.0)
    actions = _drive(follower, 8)
    assert (actions[:, 2] == -1.0).all() and np.abs(actions).max() <= 1.0
    assert follower.last_stop_probability < 1e-6


def test_stop_threshold_is_the_decision_boundary():
    follower = _follower(stop_threshold=0.9)
    with torch.no_grad():
        follower.policy.stop_head[2].weight.zero_()
        follower.policy.stop_head[2].bias.fill_(1.0)  # p = 0.73 < 0.9
    assert (_drive(follower, 4)[:, 2] == -1.0).all()
    follower.reset()
    with torch.no_grad():
        follower.policy.stop_head[2].bias.fill_(3.0)  # p = 0.95 > 0.9
    assert (_drive(follower, 4)[:, 2] == 1.0).all()


def test_s1_reads_the_plan_in_the_current_frame():
    follower = _follower(n_action_steps=1)
    counter = CountingPolicy(follower.policy)
    frames = list(_frames(4))
    follower.set_plan(_plan(), frames[0][2])
    for rgb, depth, pose in frames:
        expected = follower.inputs(rgb, depth, pose)["plan"]
        follower.act(depth, pose, rgb=rgb)
        np.testing.assert_array_equal(counter.calls[-1]["plan"], expected)
    assert [c["plan"][-1] for c in counter.calls] == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert counter.calls[0]["plan"][8] == 1.0  # has a path
    assert not np.allclose(counter.calls[0]["plan"][:8], counter.calls[3]["plan"][:8])
    with pytest.raises(ValueError, match="RGB"):
        follower.act(frames[0][1], frames[0][2])


def test_without_s2_the_plan_vector_stays_empty():
    follower = _follower(use_s2=False, n_action_steps=1)
    counter = CountingPolicy(follower.policy)
    _drive(follower, 4, plan_at=(0, 2))
    assert follower.memory.plan is None
    for t, call in enumerate(counter.calls):
        assert not call["plan"][:-1].any()
        assert call["plan"][-1] == pytest.approx(t / 10)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (dict(kind="neural"), r"model\.s1\.kind"),
        (dict(image_size=18), r"model\.s1\.image_size=18 must be divisible by 4"),
        (dict(image_size=4), r"model\.s1\.image_size=4 must be in \[8, 128\]"),
        (dict(channels=[]), r"model\.s1\.channels"),
        (dict(head=HeadConfig(action_dim=3)), r"model\.s1\.head\.action_dim=3 must be 2"),
        (
            dict(head=HeadConfig(action_dim=2, context_dim=64)),
            r"model\.s1\.head\.context_dim=64 contradicts model\.s1\.dim=32",
        ),
        (
            dict(n_action_steps=5),
            r"model\.s1\.n_action_steps=5 must be <= model\.s1\.head\.horizon=4",
        ),
        (dict(stop_threshold=1.0), r"model\.s1\.stop_threshold"),
        (dict(path_points=[0.5, 0.0]), r"model\.s1\.path_points"),
        (dict(max_depth=0.0), r"model\.s1\.max_depth"),
    ],
)
def test_config_errors_name_the_key(changes, message):
    with pytest.raises(ValueError, match=message):
        tiny_s1(**changes)


def test_config_errors_name_the_key_through_the_config_loader():
    from vla_gr.configs import ConfigError, load_config

    with pytest.raises(ConfigError, match=r"model\.s1\.image_size=20"):
        load_config("config_debug", ["model.s1.image_size=20"])
    # S1's width is one key: the head's context follows it
    _, cfg = load_config("config_debug", ["model.s1.dim=48", "model.s1.head.hidden_dim=32"])
    assert S1Policy(cfg.model.s1).head.context_dim == 48


def test_the_depth_guard_limits_forward_speed_as_the_pursuit_check_does():
    guard = PursuitConfig()
    free, guarded = _follower(seed=1), _follower(seed=1)
    guarded.guard = guard
    with torch.no_grad():
        for f in (free, guarded):
            f.policy.stop_head[2].bias.fill_(-50.0)  # never STOP
    guarded.policy.load_state_dict(free.policy.state_dict())
    rgb = np.zeros((32, 32, 3), np.uint8)
    pose = np.zeros(3)
    for follower in (free, guarded):
        follower.set_plan(_plan(), pose)
    # a wall 0.5 m ahead fills the view: between stop_distance (0.25) and slow_distance (0.8)
    wall = np.full((32, 32, 1), 0.5, np.float32)
    clearance = clearance_ahead(wall, guard)
    assert clearance == pytest.approx(0.5, abs=1e-5)
    for _ in range(4):
        a, b = free.act(wall, pose, rgb=rgb), guarded.act(wall, pose, rgb=rgb)
        np.testing.assert_array_equal(a[1:], b[1:])  # turning and STOP untouched
        expected = guarded_speed(float(a[0]), clearance, guard)
        assert b[0] == pytest.approx(expected, abs=1e-6)
        if a[0] > 0:
            assert b[0] == pytest.approx(a[0] * (0.5 - 0.25) / (0.8 - 0.25), abs=1e-6)
        else:
            assert b[0] == a[0]  # backing up is never limited
    assert guarded_speed(0.6, 0.2, guard) == 0.0 and guarded_speed(0.6, 5.0, guard) == 0.6
