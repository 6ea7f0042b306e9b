"""Fixtures shared by the training-stage tests."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from vla_gr import __version__
from vla_gr.checkpoint import save_checkpoint
from vla_gr.configs import load_config
from vla_gr.policy import make_policy


@pytest.fixture(scope="module")
def tiny_agent(tmp_path_factory) -> Path:
    """A tiny untrained dual-system agent (hashed text in the goal head) as a checkpoint."""
    tiny = ["model.agent=dual_system", "model.goal_head.text_encoder=hashed",
            "model.encoders.text_encoder=hashed", "model.s1.channels=[8,8]"]  # fmt: skip
    resolved, cfg = load_config("config_debug", tiny)
    torch.manual_seed(0)
    tensors = {k: v.contiguous() for k, v in make_policy(cfg.model).state_dict().items()}
    state = {"step": 0, "vla_gr_version": __version__}
    folder = tmp_path_factory.mktemp("tiny")
    return save_checkpoint(folder, 0, tensors, state, OmegaConf.to_yaml(resolved), links=())
