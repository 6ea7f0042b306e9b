"""Train S2's instruction reader (:mod:`vla_gr.agent.perception.instruction_reader`).

The corpus is generated, not collected: random goal descriptions (a category, with or without
a colour, a room and a neighbour) said in the template phrasings, in the *training*
paraphrase vocabulary (:data:`vla_gr.envs.paraphrase.TRAINING`), or, as negatives, about an
object no category covers ("the lamp in the kitchen"). Labels are the description's own
fields, so they are exact. Settings are chosen on the *validation* vocabulary
(:data:`~vla_gr.envs.paraphrase.VALIDATION`); the reader is measured on the *held-out* one
(:data:`~vla_gr.envs.paraphrase.HELD_OUT`), never trained or selected on: per field, the
share of instructions it fills at ``min_confidence`` and the accuracy of what it fills. The
rest of the agent comes from ``init`` and stays fixed; the result is the agent with
``model.instruction_reader.enabled=true``.

A recipe's ``instruction_reader`` stage runs it (``training.instruction_reader.*``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.errors import UserError
from vla_gr.training.agent_stage import build_agent_from, finish_part

log = logging.getLogger(__name__)

__all__ = ["fit_reader", "reader_accuracy", "reader_corpus", "train_instruction_reader"]

#: Household objects no category covers: instructions about them name no known category.
UNKNOWN_OBJECTS: tuple[str, ...] = (
    "lamp", "fridge", "mirror", "rug", "oven", "piano", "window", "door", "clock",
    "painting", "fireplace", "microwave", "bicycle", "guitar", "suitcase", "radiator",
)  # fmt: skip


def _description(rng: np.random.Generator):
    """A random goal description (the templates' fields), drawn without a house."""
    from vla_gr.envs.instructions import Description
    from vla_gr.envs.scene import CATEGORIES, COLORS, GOAL_CATEGORIES, ROOM_TYPES

    category = str(rng.choice(GOAL_CATEGORIES))
    color = str(rng.choice(list(COLORS))) if rng.random() < 0.5 else None
    room = str(rng.choice(ROOM_TYPES)) if rng.random() < 0.45 else None
    others = [c for c in CATEGORIES if c != category]
    near = str(rng.choice(others)) if rng.random() < 0.35 else None
    return Description(category, color, room, near)


def reader_corpus(
    count: int,
    seed: int,
    vocabulary: str = "training",
    template_share: float = 0.4,
    unknown_share: float = 0.1,
    categories: Sequence[str] | None = None,
    room_types: Sequence[str] | None = None,
) -> dict:
    """``count`` instructions with labels in the order of ``categories`` / ``room_types``
    (default: the world's); a category or room outside those lists is labelled "not named".

    ``vocabulary`` "training" mixes template phrasings (``template_share``), training
    paraphrases and instructions about unknown objects (``unknown_share``); any other name in
    :data:`~vla_gr.envs.paraphrase.VOCABULARIES` ("validation", "held_out", ...) says every
    instruction in that paraphrase vocabulary; "template" only in templates.
    Returns ``instructions`` (N,) and, per field, labels (N,) int64 (0 = not named).
    """
    from vla_gr.agent.perception import InstructionReaderConfig
    from vla_gr.envs.instructions import render_instruction
    from vla_gr.envs.paraphrase import TRAINING, VOCABULARIES, paraphrase
    from vla_gr.envs.scene import category_display_name

    choices = (*VOCABULARIES, "template")
    if vocabulary not in choices:
        raise UserError(f"vocabulary={vocabulary!r} is not one of {list(choices)}")
    config = InstructionReaderConfig()
    categories = list(config.categories if categories is None else categories)
    rooms = list(config.room_types if room_types is None else room_types)

    def label(name: str | None, names: list[str]) -> int:
        return names.index(name) + 1 if name in names else 0

    rng = np.random.default_rng(seed)
    texts: list[str] = []
    labels: dict[str, list[int]] = {"category": [], "anchor": [], "room": []}
    for _ in range(count):
        desc = _description(rng)
        text = render_instruction(desc, rng)
        category = label(desc.category, categories)
        draw = rng.random()
        if vocabulary not in ("training", "template"):
            text = paraphrase(text, rng, VOCABULARIES[vocabulary])
        elif vocabulary == "training" and draw < unknown_share:
            noun = str(rng.choice(UNKNOWN_OBJECTS))
            spoken = category_display_name(desc.category)  # as render_instruction says it
            text = text.replace(spoken, noun, 1)  # the goal noun comes first
            category = 0
        elif vocabulary == "training" and draw >= unknown_share + template_share:
            text = paraphrase(text, rng, TRAINING)
        texts.append(text)
        labels["category"].append(category)
        labels["anchor"].append(label(desc.near, categories))
        labels["room"].append(label(desc.room, rooms))
    return {"instructions": texts, **{k: np.asarray(v, np.int64) for k, v in labels.items()}}


def _token_states(reader, instructions: Sequence[str], batch_size: int = 256):
    """Token states of every instruction, padded to one length: (N, L, E), mask (N, L)."""
    starts = range(0, len(instructions), batch_size)
    parts = [reader.encode(instructions[i : i + batch_size]) for i in starts]
    length = max(t.shape[1] for t, _ in parts)
    tokens = torch.cat([F.pad(t, (0, 0, 0, length - t.shape[1])) for t, _ in parts])
    mask = torch.cat([F.pad(m, (0, length - m.shape[1])) for _, m in parts])
    return tokens, mask  # (N, L, E), (N, L)


@torch.no_grad()
def reader_accuracy(reader, corpus: dict) -> dict:
    """Per field on ``corpus`` (:func:`reader_corpus`): ``accuracy`` of the most likely class,
    ``filled`` = share of instructions where it names a class at ``min_confidence``,
    ``filled_accuracy`` = how often that class is right, ``wrong_fills`` = their count."""
    from vla_gr.agent.perception.instruction_reader import FIELDS

    reader.eval()
    probs = reader.probabilities(corpus["instructions"])  # {field: (N, C)}
    out: dict = {"instructions": len(corpus["instructions"])}
    for name in FIELDS:
        p, k = probs[name].max(dim=1)  # (N,), (N,)
        label = torch.from_numpy(corpus[name])
        filled = (p >= reader.config.min_confidence) & (k > 0)  # (N,)
        right = k == label  # (N,)
        out[name] = {
            "accuracy": round(float(right.float().mean()), 4),
            "filled": round(float(filled.float().mean()), 4),
            "filled_accuracy": round(float(right[filled].float().mean()), 4)
            if bool(filled.any())
            else None,
            "wrong_fills": int((filled & ~right).sum()),
            "named": round(float((label > 0).float().mean()), 4),
        }
    return out


def fit_reader(
    reader,
    corpus: dict,
    steps: int,
    batch_size: int = 256,
    lr: float = 2e-3,
    seed: int = 0,
    token_dropout: float = 0.0,
) -> list[float]:
    """Fit ``reader`` to ``corpus`` (:func:`reader_corpus`) with AdamW on the summed
    cross-entropy of its fields; each training token but the first is hidden from the
    attention with probability ``token_dropout``. Returns the loss per step."""
    from vla_gr.agent.perception.instruction_reader import FIELDS

    if not 0.0 <= token_dropout < 1.0:
        raise UserError(f"token_dropout={token_dropout} must be in [0, 1)")
    tokens, mask = _token_states(reader, corpus["instructions"])  # (N, L, E), (N, L)
    labels = {name: torch.from_numpy(corpus[name]) for name in FIELDS}
    reader.requires_grad_(True)
    optimizer = torch.optim.AdamW(reader.parameters(), lr=lr, weight_decay=1e-4)
    generator = torch.Generator().manual_seed(seed)
    reader.train()
    losses = []
    for step in range(steps):
        idx = torch.randint(len(tokens), (batch_size,), generator=generator)  # (b,)
        keep = mask[idx].clone()  # (b, L)
        if token_dropout > 0:
            dropped = torch.rand(keep.shape, generator=generator) < token_dropout  # (b, L)
            dropped[:, 0] = False  # every instruction keeps at least its first token
            keep[dropped] = 0
        logits = reader(tokens[idx], keep)  # {field: (b, C)}
        loss = sum(F.cross_entropy(logits[n], labels[n][idx]) for n in FIELDS)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
        if (step + 1) % 250 == 0:
            log.info("instruction reader step %d: loss %.4f", step + 1, np.mean(losses[-250:]))
    reader.eval()
    return losses


def train_instruction_reader(
    init: str | Path,
    out: str | Path,
    count: int = 12000,
    steps: int = 1500,
    batch_size: int = 256,
    lr: float = 2e-3,
    seed: int = 0,
    settings: Sequence[str] = (),
    eval_count: int = 2000,
    token_dropout: float = 0.0,
) -> dict:
    """Train the reader on a generated corpus and write the agent to ``out``; returns the
    summary (training loss; accuracy on fresh instructions of the training vocabulary, of
    the templates and of the validation vocabulary; on the held-out one under ``eval``)."""
    torch.manual_seed(seed)
    policy, loaded, config = build_agent_from(
        init, "instruction_reader", settings, keep_part=False,
        forced=["instruction_reader.enabled=true"],
    )  # fmt: skip
    reader = policy.instruction_reader
    policy.requires_grad_(False)
    classes = {"categories": reader.config.categories, "room_types": reader.config.room_types}

    def corpus(n: int, corpus_seed: int, vocabulary: str = "training") -> dict:
        return reader_corpus(n, corpus_seed, vocabulary, **classes)

    losses = fit_reader(reader, corpus(count, seed), steps, batch_size, lr, seed, token_dropout)
    summary = {
        "corpus": count,
        "steps": steps,
        "token_dropout": token_dropout,
        "final_loss": round(float(np.mean(losses[-100:])), 5),
        "training_vocabulary": reader_accuracy(reader, corpus(eval_count, seed + 1)),
        "templates": reader_accuracy(reader, corpus(eval_count, seed + 2, "template")),
        "validation_vocabulary": reader_accuracy(
            reader, corpus(eval_count, seed + 4, "validation")
        ),
    }
    held_out = corpus(eval_count, seed + 3, "held_out")
    return finish_part(
        policy, loaded, config, out, "instruction_reader", summary,
        lambda corpus: reader_accuracy(reader, corpus), held_out,
    )  # fmt: skip
