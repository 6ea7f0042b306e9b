"""Running statistics and min-max normalisation to [-1, 1] (as diffusion_policy's normalizer).

Statistics are kept as mergeable moments (count, sum, sum of squares, min, max) so a store
can update them on every appended episode without re-reading old data; ``mean``/``std`` are
derived. Everything here is pure: plain dicts in, plain dicts / arrays out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

#: Dimensions whose stored range is below this are treated as constant (mapped to 0).
RANGE_EPS = 1e-4


def compute_stats(x: np.ndarray) -> dict:
    """Moments of ``x`` (N, D) per dimension D, ignoring non-finite values.

    Returns a JSON-able dict with ``count`` (D,), ``sum``, ``sumsq``, ``min``, ``max``,
    ``mean`` and ``std`` (each a list of D floats).
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"compute_stats: x must be (N, D), got shape {x.shape}")
    finite = np.isfinite(x)  # (N, D)
    xf = np.where(finite, x, 0.0)  # (N, D)
    raw = {
        "count": finite.sum(0).astype(np.float64),
        "sum": xf.sum(0),
        "sumsq": (xf**2).sum(0),
        "min": np.where(finite, x, np.inf).min(0, initial=np.inf),
        "max": np.where(finite, x, -np.inf).max(0, initial=-np.inf),
    }
    return _finish(raw)


def merge_stats(a: Mapping | None, b: Mapping | None) -> dict | None:
    """Statistics of the union of the samples summarised by ``a`` and ``b`` (either may be None)."""
    if a is None:
        return None if b is None else dict(b)
    if b is None:
        return dict(a)
    raw = {
        "count": np.asarray(a["count"]) + np.asarray(b["count"]),
        "sum": np.asarray(a["sum"]) + np.asarray(b["sum"]),
        "sumsq": np.asarray(a["sumsq"]) + np.asarray(b["sumsq"]),
        "min": np.fmin(_arr(a["min"]), _arr(b["min"])),  # fmin: None (nan) = empty
        "max": np.fmax(_arr(a["max"]), _arr(b["max"])),
    }
    return _finish(raw)


def _arr(values) -> np.ndarray:
    """JSON floats (None stands for an infinite bound) -> float64 array."""
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def _finish(raw: dict) -> dict:
    count = np.maximum(raw["count"], 1.0)
    mean = raw["sum"] / count
    var = np.maximum(raw["sumsq"] / count - mean**2, 0.0)
    out = {k: np.asarray(v, dtype=np.float64) for k, v in raw.items()}
    out["mean"] = mean
    out["std"] = np.sqrt(var)
    # JSON has no inf: an empty dimension's bounds become None.
    return {k: [None if not np.isfinite(x) else float(x) for x in v] for k, v in out.items()}


@dataclass(frozen=True)
class MinMaxNormalizer:
    """Affine map of each dimension from [min, max] to [-1, 1], and its inverse.

    Constant dimensions (range < ``RANGE_EPS``) map to ``x - min`` (0 at the stored value),
    exactly as diffusion_policy's ``LinearNormalizer`` does.
    """

    scale: np.ndarray  # (D,)
    offset: np.ndarray  # (D,)

    @classmethod
    def from_min_max(cls, vmin, vmax) -> MinMaxNormalizer:
        """Build from per-dimension bounds ``vmin``, ``vmax`` (D,)."""
        vmin = np.asarray(vmin, dtype=np.float64)
        vmax = np.asarray(vmax, dtype=np.float64)
        if vmin.shape != vmax.shape or vmin.ndim != 1:
            raise ValueError(f"vmin {vmin.shape} and vmax {vmax.shape} must be equal (D,) shapes")
        if not (np.isfinite(vmin).all() and np.isfinite(vmax).all()):
            raise ValueError("vmin/vmax must be finite (are the statistics empty?)")
        if (vmax < vmin).any():
            raise ValueError(f"vmax {vmax.tolist()} is below vmin {vmin.tolist()}")
        rng = vmax - vmin  # (D,)
        constant = rng < RANGE_EPS
        rng = np.where(constant, 2.0, rng)
        scale = 2.0 / rng
        offset = np.where(constant, -vmin, -1.0 - scale * vmin)
        return cls(scale=scale, offset=offset)

    @classmethod
    def from_stats(cls, stats: Mapping) -> MinMaxNormalizer:
        """Build from a ``compute_stats``/``merge_stats`` dict."""
        return cls.from_min_max(_arr(stats["min"]), _arr(stats["max"]))

    def normalize(self, x):
        """Map ``x`` (..., D) (numpy or torch) to [-1, 1]."""
        scale, offset = self._like(x)
        return x * scale + offset

    def unnormalize(self, y):
        """Inverse of ``normalize`` for ``y`` (..., D) (numpy or torch)."""
        scale, offset = self._like(y)
        return (y - offset) / scale

    def _like(self, x):
        if x.shape[-1] != self.scale.shape[0]:
            raise ValueError(f"last dim of input {tuple(x.shape)} must be {self.scale.shape[0]}")
        if type(x).__module__.startswith("torch"):
            import torch

            return (
                torch.as_tensor(self.scale, dtype=x.dtype, device=x.device),
                torch.as_tensor(self.offset, dtype=x.dtype, device=x.device),
            )
        dtype = x.dtype if np.issubdtype(np.asarray(x).dtype, np.floating) else np.float64
        return self.scale.astype(dtype), self.offset.astype(dtype)

    def to_dict(self) -> dict:
        return {"scale": self.scale.tolist(), "offset": self.offset.tolist()}

    @classmethod
    def from_dict(cls, d: Mapping) -> MinMaxNormalizer:
        return cls(scale=np.asarray(d["scale"], float), offset=np.asarray(d["offset"], float))


def normalizers_from_stats(stats: Mapping, keys=("action", "pose")) -> dict[str, MinMaxNormalizer]:
    """One ``MinMaxNormalizer`` per key of a store's statistics."""
    missing = [k for k in keys if k not in stats or stats[k] is None]
    if missing:
        raise ValueError(f"statistics have no entry for {missing}; available: {sorted(stats)}")
    return {k: MinMaxNormalizer.from_stats(stats[k]) for k in keys}
