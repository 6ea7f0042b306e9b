"""Whether a request asks the robot to go somewhere at all.

"that green chair is honestly so ugly lol" names a goal, a colour and nothing the tagger can
object to, yet asks for nothing. :class:`RequestIntent` reads the whole sentence (the frozen
encoder's word states, the tagger's inputs) and gives the probability that it asks the robot
to go to something; below ``model.instruction_reader.min_intent`` the reader does
not act on the request. It learns from requests of the request grammar against statements,
questions and remarks of real English (:mod:`vla_gr.training.remark_corpus`).
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["RequestIntent", "pooled_states"]


def pooled_states(states: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The mean word state (B, E) of word states (B, N, E) under the word mask (B, N); zeros
    for an empty request."""
    weights = mask.unsqueeze(-1).to(states.dtype)  # (B, N, 1)
    return (states * weights).sum(dim=1) / weights.sum(dim=1).clamp(min=1.0)  # (B, E)


class RequestIntent(nn.Module):
    """(word states (B, N, E), mask (B, N)) -> logit (B,) that the request asks the robot to
    go to something: a bidirectional GRU over the words (the order tells "the red chair" from
    "the red chair is ugly"), its outputs' masked mean and max."""

    def __init__(self, token_dim: int = 384, hidden: int = 64) -> None:
        super().__init__()
        self.project = nn.Sequential(nn.Linear(token_dim, hidden), nn.SiLU())
        self.gru = nn.GRU(hidden, hidden, batch_first=True, bidirectional=True)
        self.out = nn.Linear(4 * hidden, 1)

    def forward(self, states: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        if states.shape[1] == 0:  # no word at all: the GRU has nothing to read
            return self.out.bias.expand(states.shape[0])  # (B,)
        x = self.project(states)  # (B, N, H)
        lengths = mask.sum(dim=1).clamp(min=1).cpu()  # (B,)
        packed = nn.utils.rnn.pack_padded_sequence(
            x, lengths, batch_first=True, enforce_sorted=False
        )
        out, _ = self.gru(packed)
        out, _ = nn.utils.rnn.pad_packed_sequence(out, batch_first=True, total_length=x.shape[1])
        mean = pooled_states(out, mask)  # (B, 2H)
        biggest = out.masked_fill(mask.unsqueeze(-1) == 0, float("-inf")).amax(dim=1)  # (B, 2H)
        biggest = torch.where(torch.isfinite(biggest), biggest, torch.zeros_like(biggest))
        return self.out(torch.cat([mean, biggest], dim=-1)).squeeze(-1)  # (B,)
