"""Train the instruction reader's request intent head (:mod:`vla_gr.agent.reading.intent`)
and write it into the agent; the agent's tagger, its temperature and ``min_confidence`` stay.

The head learns whether a sentence asks the robot to go somewhere from the intent corpus
(:func:`~vla_gr.training.remark_corpus.intent_corpus`: grammar requests against WordNet's
statements, half with a house object put in). ``min_intent`` is chosen on the development
sets of hand-written requests: the most requests read right and acted on, a refusal acted on
counting twice against. A recipe's ``request_intent`` stage runs it
(``training.request_intent.*``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.training.agent_stage import build_agent_from, finish_part
from vla_gr.training.distributed import process_rank, rank_share
from vla_gr.training.part_training import ON_CPU, Compute, PartTrainer, rank_seed

log = logging.getLogger(__name__)

__all__ = [
    "INTENT_THRESHOLDS",
    "calibrate_intent",
    "encode_sentences",
    "fit_intent",
    "intent_accuracy",
    "train_request_intent",
]

#: The ``min_intent`` values the development sets choose from.
INTENT_THRESHOLDS = (0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)


@torch.no_grad()
def encode_sentences(reader, texts: Sequence[str], batch: int = 128) -> dict:
    """The intent head's inputs of ``texts``: word states (N, W, E) in half precision and the
    word mask (N, W)."""
    from vla_gr.agent.reading.text import normalise_request, request_words

    sentences = [request_words(normalise_request(t)) for t in texts]
    width = max((len(words) for words in sentences), default=0)
    states, masks = [], []
    for start in range(0, len(sentences), batch):
        _, part, _, mask = reader.inputs(sentences[start : start + batch])  # (b, w, E), (b, w)
        pad = width - part.shape[1]
        states.append(F.pad(part, (0, 0, 0, pad)).half())
        masks.append(F.pad(mask, (0, pad)))
        if (start // batch) % 20 == 0:
            log.info("encoded %d / %d sentences", start + part.shape[0], len(sentences))
    return {"states": torch.cat(states), "mask": torch.cat(masks)}


def fit_intent(
    reader, corpus: dict, labels: torch.Tensor, steps: int, batch_size: int, lr: float,
    seed: int, compute: Compute = ON_CPU,
) -> list[float]:  # fmt: skip
    """AdamW on the intent head's binary cross-entropy over an encoded corpus
    (:func:`encode_sentences`) and its labels (N,); returns the loss per step. The head ends
    on the CPU, in eval mode."""
    head = reader.intent.requires_grad_(True).train()

    def loss(states, mask, y) -> torch.Tensor:
        return F.binary_cross_entropy_with_logits(head(states, mask), y)  # (b,) vs (b,)

    trainer = PartTrainer(head, loss, compute)
    optimizer = torch.optim.AdamW(head.parameters(), lr=lr, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps)
    generator = torch.Generator().manual_seed(rank_seed(seed))
    losses = []
    for step in range(steps):
        idx = torch.randint(len(labels), (batch_size,), generator=generator)  # (b,)
        mask = corpus["mask"][idx]  # (b, W)
        width = max(int(mask.sum(dim=1).max()), 1)
        batch = {"states": corpus["states"][idx, :width].float(), "mask": mask[:, :width],
                 "y": labels[idx]}  # fmt: skip
        losses.append(trainer.step(batch, optimizer, schedule))
        if (step + 1) % 500 == 0:
            log.info("intent step %d: loss %.4f", step + 1, np.mean(losses[-500:]))
    head.cpu()
    reader.eval()
    return losses


@torch.no_grad()
def intent_accuracy(reader, corpus: dict, labels: Sequence[int]) -> float:
    """Share of an encoded corpus the intent head classifies right (at probability 0.5)."""
    said = reader.intent(corpus["states"].float(), corpus["mask"]) > 0  # (N,)
    return float((said == torch.tensor(labels, dtype=torch.bool)).float().mean())


def calibrate_intent(reader, rows: list[dict]) -> dict:
    """Set ``min_intent`` on development ``rows`` (the most asks read right and acted on; an
    ask acted on wrongly, or a refusal acted on, counts -2); returns the choice, the scores at
    it and without the head's refusals."""
    from vla_gr.agent.reading.text import normalise_request, request_words
    from vla_gr.training.reader_training import development_merit, reading_scores

    c = reader.config
    texts = [normalise_request(row["request"]) for row in rows]
    words, probs, intents = reader.tag_probabilities([request_words(t) for t in texts])

    def scores(threshold: float) -> dict:
        saved, c.min_intent = c.min_intent, threshold
        try:
            readings = [reader.decode(*read) for read in zip(texts, words, probs, intents)]
        finally:
            c.min_intent = saved
        return reading_scores(readings, rows)

    table = {th: scores(th) for th in (0.0, *INTENT_THRESHOLDS)}
    c.min_intent = max(INTENT_THRESHOLDS, key=lambda th: (development_merit(table[th]), -th))
    reader._cache.clear()
    return {"min_intent": c.min_intent, "dev": table[c.min_intent], "dev_without": table[0.0]}


def train_request_intent(
    init: str | Path,
    out: str | Path,
    dev_sets: Sequence[str | Path],
    count: int = 8000,
    steps: int = 1500,
    batch_size: int = 256,
    lr: float = 3e-3,
    seed: int = 0,
    compute: Compute = ON_CPU,
) -> dict:
    """Train the intent head of checkpoint ``init``'s reader on ``count`` grammar requests and
    ``count`` remarks, choose ``min_intent`` on ``dev_sets`` and write the agent to ``out``;
    returns the summary (loss, accuracy on a fresh corpus, the development scores). Under
    torchrun each rank encodes and draws from its own share (data parallel); rank 0 alone
    measures, calibrates and writes."""
    from vla_gr.agent.reading.vocabulary import word_table
    from vla_gr.training.reader_training import load_request_rows
    from vla_gr.training.remark_corpus import intent_corpus
    from vla_gr.training.request_grammar import RequestGrammar

    dev_rows = load_request_rows(dev_sets)  # a missing file fails before any training
    torch.manual_seed(seed)
    policy, loaded, config = build_agent_from(
        init, "instruction_reader", [], keep_part=True, forced=["instruction_reader.intent=true"],
        reinit=["instruction_reader.intent."],  # trained from scratch, whatever init holds
    )  # fmt: skip
    reader = policy.instruction_reader
    policy.requires_grad_(False)
    c = reader.config
    grammar = RequestGrammar(word_table(), c.goal_categories, c.categories, c.room_types)
    texts, labels = intent_corpus(grammar, count, seed)
    rank, world = process_rank()
    share = rank_share(0, len(texts), rank, world)  # the sentences this rank encodes
    texts, labels = texts[share.start : share.stop], labels[share.start : share.stop]
    y = torch.tensor(labels, dtype=torch.float32)  # (N,)
    corpus = encode_sentences(reader, texts)
    losses = fit_intent(reader, corpus, y, steps, batch_size, lr, seed, compute)
    if rank != 0:
        return {"corpus": len(texts), "steps": steps}
    held_texts, held_labels = intent_corpus(grammar, max(count // 10, 100), seed + 10)
    summary = {
        "corpus": len(texts),
        "steps": steps,
        "final_loss": round(float(np.mean(losses[-100:])), 5),
        "generated_accuracy": round(
            intent_accuracy(reader, encode_sentences(reader, held_texts), held_labels), 5
        ),
        "development": calibrate_intent(reader, dev_rows),
    }
    config.model.instruction_reader.intent = True
    config.model.instruction_reader.min_intent = summary["development"]["min_intent"]
    log.info("request intent: %s", summary)
    return finish_part(policy, loaded, config, out, "request_intent", summary, None, None)
