"""Train the instruction reader's tagger on the request grammar and calibrate it on a
development set of hand-written requests.

The corpus is generated (:class:`~vla_gr.training.request_grammar.RequestGrammar`): every word
carries its role, so labels are exact. The development sets are JSONL files of hand-written
requests (``benchmarks/language/``): lines with ``fields`` (what the request names) and lines
with a ``kind`` (requests the agent must not act on). They choose the temperature (the
lowest expected calibration error of the field confidences) and ``min_confidence`` (the most
requests read right and acted on, a request acted on wrongly counting twice against). Blind
sets are never read here.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.agent.reading.reader import FIELDS, InstructionReader
from vla_gr.agent.reading.tagger import TAGS
from vla_gr.errors import UserError
from vla_gr.training.part_training import ON_CPU, Compute, PartTrainer, rank_seed

log = logging.getLogger(__name__)

__all__ = [
    "calibrate_reader",
    "development_merit",
    "encode_corpus",
    "expected_calibration_error",
    "fit_tagger",
    "load_request_rows",
    "reading_scores",
    "tag_accuracy",
]

TEMPERATURES = (0.5, 0.7, 1.0, 1.4, 2.0, 2.8)
THRESHOLDS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


def encode_corpus(reader: InstructionReader, requests, batch: int = 128) -> dict:
    """Tagger inputs of labelled requests: states (N, W, E) half, features (N, W, F),
    mask (N, W), labels (N, W) (-100 on padding)."""
    width = max(len(r.words) for r in requests)
    chunks = {"states": [], "features": [], "mask": [], "labels": []}
    for start in range(0, len(requests), batch):
        part = requests[start : start + batch]
        _, states, feats, mask = reader.inputs([list(r.words) for r in part])
        pad = width - states.shape[1]
        labels = torch.full((len(part), width), -100, dtype=torch.long)
        for b, r in enumerate(part):
            labels[b, : len(r.tags)] = torch.tensor([TAGS.index(t) for t in r.tags])
        chunks["states"].append(F.pad(states, (0, 0, 0, pad)).half())
        chunks["features"].append(F.pad(feats, (0, 0, 0, pad)))
        chunks["mask"].append(F.pad(mask, (0, pad)))
        chunks["labels"].append(labels)
        if (start // batch) % 20 == 0:
            log.info("encoded %d / %d requests", start + len(part), len(requests))
    return {k: torch.cat(v) for k, v in chunks.items()}


def fit_tagger(
    reader: InstructionReader,
    corpus: dict,
    steps: int,
    batch_size: int,
    lr: float,
    seed: int,
    compute: Compute = ON_CPU,
) -> list[float]:
    """AdamW on the tagger's per-word cross-entropy on ``compute``'s device and precision
    (``batch_size`` requests per rank under torchrun); returns the loss per step. The tagger
    ends on the CPU, in eval mode."""
    tagger = reader.tagger.requires_grad_(True).train()

    def loss(states, features, mask, labels) -> torch.Tensor:
        logits = tagger(states, features, mask)  # (b, w, T)
        return F.cross_entropy(logits.reshape(-1, len(TAGS)), labels.reshape(-1), ignore_index=-100)

    trainer = PartTrainer(tagger, loss, compute)
    optimizer = torch.optim.AdamW(tagger.parameters(), lr=lr, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps)
    generator = torch.Generator().manual_seed(rank_seed(seed))
    n = len(corpus["labels"])
    losses = []
    for step in range(steps):
        idx = torch.randint(n, (batch_size,), generator=generator)  # (b,)
        mask = corpus["mask"][idx]  # (b, W)
        width = int(mask.sum(dim=1).max())
        batch = {
            "states": corpus["states"][idx, :width].float(),  # (b, w, E)
            "features": corpus["features"][idx, :width],  # (b, w, F)
            "mask": mask[:, :width],  # (b, w)
            "labels": corpus["labels"][idx, :width],  # (b, w)
        }
        losses.append(trainer.step(batch, optimizer, schedule))
        if (step + 1) % 200 == 0:
            log.info("tagger step %d: loss %.4f", step + 1, np.mean(losses[-200:]))
    tagger.cpu()
    reader.eval()
    return losses


@torch.no_grad()
def tag_accuracy(reader: InstructionReader, corpus: dict) -> float:
    """Share of the words of an encoded corpus the tagger tags right."""
    logits = reader.tagger(corpus["states"].float(), corpus["features"], corpus["mask"])
    labels = corpus["labels"]  # (N, W)
    real = labels != -100
    return float((logits.argmax(dim=-1)[real] == labels[real]).float().mean())


def load_request_rows(paths: Sequence[str | Path]) -> list[dict]:
    """Hand-written request lines: {"request", "fields"} (and "kind" for requests the agent
    must not act on) from JSONL files; UserError naming a missing file."""
    rows = []
    for path in paths:
        path = Path(path)
        if not path.is_file():
            raise UserError(f"request set {str(path)!r} does not exist")
        for line in path.read_text(encoding="utf-8").splitlines():
            if line.strip():
                row = json.loads(line)
                rows.append({"request": row["request"], "fields": row["fields"],
                             "refuse": "kind" in row})  # fmt: skip
    return rows


def _expected(row: dict) -> dict:
    f = row["fields"]
    return {"category": f["category"], "color": f["color"], "room": f["room"], "anchor": f["near"]}


def expected_calibration_error(confidences, correct, bins: int = 10) -> float:
    """ECE: the bin-weighted gap between mean confidence and accuracy (equal-width bins)."""
    conf = np.asarray(confidences, dtype=np.float64)
    hit = np.asarray(correct, dtype=np.float64)
    if len(conf) == 0:
        return 0.0
    which = np.minimum((conf * bins).astype(int), bins - 1)
    total = 0.0
    for b in range(bins):
        sel = which == b
        if sel.any():
            total += sel.mean() * abs(conf[sel].mean() - hit[sel].mean())
    return float(total)


def reading_scores(readings, rows: list[dict]) -> dict:
    """Per set: reading accuracy (every field right), per-field accuracy, understood share,
    acted-on-wrongly count, field-confidence ECE; refusals: share not understood."""
    asks = [(r, row) for r, row in zip(readings, rows) if not row["refuse"]]
    refusals = [r for r, row in zip(readings, rows) if row["refuse"]]
    out: dict = {}
    if asks:
        conf, hit, right = [], [], []
        per_field = {name: [] for name in FIELDS}
        for reading, row in asks:
            want = _expected(row)
            ok = [getattr(reading, n) == want[n] for n in FIELDS]
            for name, good in zip(FIELDS, ok):
                per_field[name].append(good)
                conf.append(reading.confidence[name])
                hit.append(good)
            right.append(all(ok))
        understood = [r.understood for r, _ in asks]
        out.update(
            requests=len(asks),
            reading_accuracy=float(np.mean(right)),
            field_accuracy={n: float(np.mean(v)) for n, v in per_field.items()},
            understood=float(np.mean(understood)),
            understood_and_right=float(np.mean([u and g for u, g in zip(understood, right)])),
            acted_on_wrongly=int(sum(u and not g for u, g in zip(understood, right))),
            ece=expected_calibration_error(conf, hit),
        )
    if refusals:
        out.update(
            refusals=len(refusals),
            refused=float(np.mean([not r.understood for r in refusals])),
        )
    return out


def development_merit(scores: dict) -> float:
    """What a calibration maximises on development :func:`reading_scores`: asks read right and
    acted on, an ask acted on wrongly or a refusal acted on counting -2."""
    acted_refusals = scores.get("refusals", 0) * (1.0 - scores.get("refused", 1.0))
    return (
        scores.get("understood_and_right", 0.0) * scores.get("requests", 0)
        - 2.0 * scores.get("acted_on_wrongly", 0)
        - 2.0 * acted_refusals
    )


def calibrate_reader(reader: InstructionReader, rows: list[dict]) -> dict:
    """Set ``temperature`` (lowest field ECE on the asks) then ``min_confidence`` (most asks
    read right and acted on; an ask acted on wrongly, or a refusal acted on, counts -2) on
    development ``rows``; returns the choice and the scores at it."""
    from vla_gr.agent.reading.text import normalise_request, request_words

    c = reader.config
    texts = [normalise_request(row["request"]) for row in rows]
    words, logits, intents = reader.tag_logits([request_words(t) for t in texts])  # once

    def scores(temperature: float, threshold: float) -> dict:
        saved = c.min_confidence
        c.min_confidence = threshold
        try:
            readings = [
                reader.decode(t, w, torch.softmax(x / temperature, dim=-1), p)
                for t, w, x, p in zip(texts, words, logits, intents)
            ]
        finally:
            c.min_confidence = saved
        return reading_scores(readings, rows)

    best_t = min(TEMPERATURES, key=lambda t: scores(t, 0.0).get("ece", 0.0))

    c.temperature = best_t
    c.min_confidence = max(THRESHOLDS, key=lambda th: (development_merit(scores(best_t, th)), -th))
    reader._cache.clear()
    return {
        "temperature": c.temperature,
        "min_confidence": c.min_confidence,
        "dev": scores(c.temperature, c.min_confidence),
    }
