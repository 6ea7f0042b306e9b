"""Which role each word of a request plays: the goal noun, its colour, its room, the anchor
of a relation, a negation, a second goal, or none.

:class:`RequestTagger` reads, per word, the frozen sentence encoder's token state (the mean of
the word's sub-word tokens) and what the word tables say of it
(:data:`~vla_gr.agent.reading.vocabulary.FEATURES`: a colour word, a category or room word,
a relation or negation word, a repaired typing slip, ...), and tags it with a bidirectional
GRU over the words. The encoder knows the sentence's shape ("the chair *next to the* tv");
the tables know the words, so a synonym the grammar never used is still a category word.
"""

from __future__ import annotations

import torch
from torch import nn

from vla_gr.agent.reading.vocabulary import FEATURES

__all__ = ["TAGS", "RequestTagger", "word_states"]

#: The roles, in the order of the tagger's outputs.
TAGS: tuple[str, ...] = ("O", "GOAL", "COLOUR", "ROOM", "ANCHOR", "NEG", "SECOND")


class RequestTagger(nn.Module):
    """(token states (B, N, E), features (B, N, F), mask (B, N)) -> tag logits (B, N, T)."""

    def __init__(self, token_dim: int = 384, hidden: int = 96) -> None:
        super().__init__()
        self.project = nn.Sequential(nn.Linear(token_dim, hidden), nn.SiLU())
        self.gru = nn.GRU(hidden + len(FEATURES), hidden, batch_first=True, bidirectional=True)
        self.out = nn.Linear(2 * hidden, len(TAGS))

    def forward(
        self, states: torch.Tensor, features: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        x = torch.cat([self.project(states), features], dim=-1)  # (B, N, H + F)
        lengths = mask.sum(dim=1).clamp(min=1).cpu()  # (B,)
        packed = nn.utils.rnn.pack_padded_sequence(
            x, lengths, batch_first=True, enforce_sorted=False
        )
        out, _ = self.gru(packed)
        out, _ = nn.utils.rnn.pad_packed_sequence(out, batch_first=True, total_length=x.shape[1])
        return self.out(out)  # (B, N, T)


@torch.no_grad()
def word_states(model, sentences: list[list[str]]) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-word token states (B, N, E) of word lists ``sentences`` from the frozen encoder
    ``model`` (the mean of each word's sub-word tokens) and the word mask (B, N).

    A word cut off by the encoder's length limit gets a zero state (still masked in)."""
    width = max((len(s) for s in sentences), default=0)
    batch = len(sentences)
    if width == 0:
        return torch.zeros(batch, 0, model.dim), torch.zeros(batch, 0, dtype=torch.long)
    encoded = model.tokenizer(
        sentences,
        is_split_into_words=True,
        padding=True,
        truncation=True,
        max_length=model.max_length,
        return_tensors="pt",
    )
    hidden = model.model(
        input_ids=encoded["input_ids"], attention_mask=encoded["attention_mask"]
    ).last_hidden_state.float()  # (B, L, E)
    states = torch.zeros(batch, width, hidden.shape[-1])  # (B, N, E)
    counts = torch.zeros(batch, width, 1)  # (B, N, 1)
    for b in range(batch):
        for position, word in enumerate(encoded.word_ids(b)):
            if word is not None:
                states[b, word] += hidden[b, position]
                counts[b, word] += 1
    mask = torch.zeros(batch, width, dtype=torch.long)  # (B, N)
    for b, sentence in enumerate(sentences):
        mask[b, : len(sentence)] = 1
    return states / counts.clamp(min=1), mask
