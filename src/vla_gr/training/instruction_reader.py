"""Train the agent's instruction reader (:mod:`vla_gr.agent.reading`) and write it into the
agent.

The tagger learns from the request grammar (:mod:`vla_gr.training.request_grammar`: labels
are exact, every word's role is known); the development sets of hand-written requests choose
its temperature and ``min_confidence``
(:func:`~vla_gr.training.reader_training.calibrate_reader`). The rest of the agent comes from
``init`` and stays fixed; the result is the agent with ``model.instruction_reader.enabled=true``.
A recipe's ``instruction_reader`` stage runs it (``training.instruction_reader.*``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from vla_gr.training.agent_stage import build_agent_from, finish_part
from vla_gr.training.distributed import process_rank, rank_share
from vla_gr.training.part_training import ON_CPU, Compute

log = logging.getLogger(__name__)

__all__ = ["train_instruction_reader"]


def train_instruction_reader(
    init: str | Path,
    out: str | Path,
    dev_sets: Sequence[str | Path],
    count: int = 12000,
    steps: int = 2000,
    batch_size: int = 128,
    lr: float = 3e-3,
    seed: int = 0,
    settings: Sequence[str] = (),
    compute: Compute = ON_CPU,
) -> dict:
    """Train the tagger on ``count`` generated requests, calibrate it on ``dev_sets`` and write
    the agent to ``out``; returns the summary (training loss; tag accuracy on fresh generated
    requests; the development scores at the chosen temperature and threshold). The tagger trains
    on ``compute``'s device and precision; under torchrun each rank encodes and draws from its
    own share of the requests (data parallel), and rank 0 alone measures, calibrates and writes
    (the other ranks return ``corpus`` and ``steps``)."""
    from vla_gr.agent.reading.vocabulary import word_table
    from vla_gr.training.reader_training import (
        calibrate_reader,
        encode_corpus,
        fit_tagger,
        load_request_rows,
        tag_accuracy,
    )
    from vla_gr.training.request_grammar import RequestGrammar

    dev_rows = load_request_rows(dev_sets)  # a missing file fails before any training
    torch.manual_seed(seed)
    policy, loaded, config = build_agent_from(
        init, "instruction_reader", settings, keep_part=False,
        forced=["instruction_reader.enabled=true"],
    )  # fmt: skip
    reader = policy.instruction_reader
    policy.requires_grad_(False)
    c = reader.config
    grammar = RequestGrammar(word_table(), c.goal_categories, c.categories, c.room_types)
    rank, world = process_rank()
    share = rank_share(0, count, rank, world)  # the requests this rank encodes
    requests = grammar.batch(count, seed)[share.start : share.stop]
    losses = fit_tagger(reader, encode_corpus(reader, requests), steps, batch_size, lr, seed,
                        compute)  # fmt: skip
    if rank != 0:
        return {"corpus": len(requests), "steps": steps}
    held = encode_corpus(reader, grammar.batch(max(count // 10, 100), seed + 1))
    summary = {
        "corpus": count,
        "steps": steps,
        "final_loss": round(float(np.mean(losses[-100:])), 5),
        "generated_tag_accuracy": round(tag_accuracy(reader, held), 5),
        "development": calibrate_reader(reader, dev_rows),
    }
    chosen = summary["development"]
    config.model.instruction_reader.temperature = chosen["temperature"]
    config.model.instruction_reader.min_confidence = chosen["min_confidence"]
    log.info("instruction reader: %s", summary)
    return finish_part(policy, loaded, config, out, "instruction_reader", summary, None, None)
