"""The shipped agent acting in the env as a user writes it: ``env.step(policy.select_action(obs))``
for one env, and a vector env whose sub-envs each get the actions a lone env gives."""

from __future__ import annotations

import functools
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from vla_gr.envs import ENV_ID
from vla_gr.policy import load_policy

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"
ENV = {"split": "val", "image_size": 64, "num_rooms": 2}  # the shipped agent's image size


@pytest.fixture(scope="module")
def policy():
    return load_policy(SHIPPED)


def lone_run(policy, env, index: int, steps: int) -> list[np.ndarray]:
    """The actions of val episode ``index`` run alone, until it ends or after ``steps``."""
    obs, _ = env.reset(options={"episode": index})
    policy.reset()
    actions = []
    for _ in range(steps):
        actions.append(policy.select_action(obs))  # (3,)
        obs, _, terminated, truncated, _ = env.step(actions[-1])
        if terminated or truncated:
            break
    return actions


def test_one_env_steps_on_the_policys_actions(policy):
    env = gym.make(ENV_ID, **ENV)
    try:
        actions = lone_run(policy, env, 3, steps=5)
    finally:
        env.close()
    assert len(actions) == 5
    assert all(a.shape == (3,) and a.dtype == np.float32 for a in actions)
    assert any(a[0] > 0.0 or a[1] != 0.0 for a in actions)  # it moves


def test_each_sub_env_gets_a_lone_envs_actions_and_its_autoreset_restarts_it_alone(policy):
    budgets = (5, 40)  # sub-env 0's episodes time out after 5 steps, sub-env 1's run on
    make = [functools.partial(gym.make, ENV_ID, max_episode_steps=m, **ENV) for m in budgets]
    vec = SyncVectorEnv(make)
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    steps = 12
    try:
        obs, info = vec.reset(seed=3)
        episodes = [[name] for name in info["episode_id"]]
        policy.reset()
        done = np.zeros(2, dtype=bool)
        got = []
        for _ in range(steps):
            got.append(policy.select_action(obs, done))  # (2, 3)
            obs, _, terminated, truncated, info = vec.step(got[-1])
            for i in np.flatnonzero(done):  # this step reset sub-env i: its new episode
                episodes[i].append(info["episode_id"][i])
            done = terminated | truncated
    finally:
        vec.close()
    assert [len(e) for e in episodes] == [3, 1]  # sub-env 0 restarted twice, sub-env 1 never
    for i, budget in enumerate(budgets):
        env = make[i]()
        try:
            expected = []
            for name in episodes[i]:  # each episode alone, then the ignored row of its end
                expected += lone_run(policy, env, int(name.split("-")[-1]), budget)
                expected.append(np.zeros(3, np.float32))
        finally:
            env.close()
        np.testing.assert_array_equal(np.stack(got)[:, i], np.stack(expected[:steps]))
