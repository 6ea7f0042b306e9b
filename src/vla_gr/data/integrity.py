"""Chunk-level integrity of an episode store: presence, CRC32C checksums, valid values.

zarr fills a missing chunk with the array's fill value and decodes flipped bytes into
wrong numbers without a word. Every chunk an episode needs is therefore checked here:

- **presence**: the chunk file exists (format-1 stores did not write chunks that were all
  fill value, so there a missing ``goal_mask`` chunk is read as all-False, as written);
- **checksum**: the last 4 bytes of the chunk are the CRC32C of the rest (zarr's
  ``crc32c`` codec, format 2); a chunk shorter than its Blosc header says is *truncated*;
- **values**: decoded rows are finite and in range (actions in [-1, 1], depth >= 0).

``scan_array`` reports bad chunks; the store maps them to episodes (``Damage``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import google_crc32c
import numpy as np
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec

#: Valid range of the decoded values of a frame key; a value outside it is damage.
VALUE_RANGES: dict[str, tuple[float, float]] = {
    "action": (-1.0, 1.0),
    "pose": (-math.inf, math.inf),
    "depth": (0.0, math.inf),
}
#: Frame keys whose values are checked on every open (small); the others with ``deep=True``.
CHEAP_VALUE_KEYS: tuple[str, ...] = ("action", "pose")


@dataclass(frozen=True)
class Damage:
    """One bad chunk: ``array`` (e.g. ``data/depth``), its ``chunk`` index along axis 0,
    the rows it holds ``[start, stop)``, the ``problem`` and the stored ``episodes`` it hits."""

    array: str
    chunk: int
    start: int
    stop: int
    problem: str
    episodes: tuple[int, ...] = ()

    def describe(self) -> str:
        eps = ", ".join(map(str, self.episodes)) if self.episodes else "none"
        return (
            f"{self.array} chunk {self.chunk} (rows {self.start}-{self.stop - 1}): "
            f"{self.problem} -> episodes {eps}"
        )


def is_checksummed(arr: zarr.Array) -> bool:
    """True when the array's last codec is CRC32C (each chunk ends in its checksum)."""
    return isinstance(arr.metadata.codecs[-1], Crc32cCodec)


def value_problem(key: str, values: np.ndarray) -> str | None:
    """Why decoded ``values`` of frame key ``key`` are invalid, or None when they are valid."""
    lo, hi = VALUE_RANGES.get(key, (None, None))
    if lo is None or values.size == 0:
        return None
    if not np.isfinite(values).all():
        return "non-finite values (NaN or inf)"
    vmin, vmax = float(values.min()), float(values.max())
    if vmin < lo or vmax > hi:
        return f"values out of range [{lo}, {hi}] (min {vmin:.6g}, max {vmax:.6g})"
    return None


def _raw_problem(raw: bytes, blosc: bool) -> str | None:
    """Checksum problem of one encoded chunk ``raw`` (payload + 4-byte CRC32C), or None."""
    if len(raw) < 4:
        return f"truncated ({len(raw)} bytes)"
    stored = int.from_bytes(raw[-4:], "little")
    if google_crc32c.value(raw[:-4]) == stored:
        return None
    if blosc and len(raw) >= 20:
        expected = int.from_bytes(raw[12:16], "little") + 4  # Blosc header: cbytes
        if len(raw) < expected:
            return f"truncated ({len(raw)} of {expected} bytes)"
    return "checksum mismatch (flipped or overwritten bytes)"


def scan_array(
    arr: zarr.Array,
    root: Path,
    name: str,
    n_rows: int,
    value_key: str | None = None,
    decode: bool = False,
    missing_ok: bool = False,
) -> list[tuple[int, int, int, str]]:
    """Bad chunks of ``root/name`` among those holding rows ``[0, n_rows)``.

    Returns ``(chunk, start, stop, problem)`` per bad chunk. ``decode`` also reads every
    chunk through zarr (and checks values when ``value_key`` has a range); ``missing_ok``
    accepts absent chunks (format-1 arrays whose all-fill chunks were never written).
    """
    rows = int(arr.chunks[0])
    tail = (0,) * (arr.ndim - 1)
    checksummed = is_checksummed(arr)
    blosc = any(isinstance(c, BloscCodec) for c in arr.metadata.codecs)
    bad: list[tuple[int, int, int, str]] = []
    for i in range(-(-n_rows // rows)):
        start, stop = i * rows, min((i + 1) * rows, n_rows)
        file = root / name / arr.metadata.encode_chunk_key((i, *tail))
        problem = None
        if not file.is_file():
            if not missing_ok:
                problem = "missing chunk (zarr would read it as fill values)"
        elif checksummed:
            problem = _raw_problem(file.read_bytes(), blosc)
        if problem is None and decode:
            try:
                values = np.asarray(arr[start:stop])
            except Exception as err:  # a codec error: the chunk cannot be decoded
                problem = f"cannot be decoded ({type(err).__name__}: {err})"
            else:
                problem = value_problem(value_key, values) if value_key else None
        if problem is not None:
            bad.append((i, start, stop, problem))
    return bad


def episodes_of_rows(ends: np.ndarray, start: int, stop: int) -> tuple[int, ...]:
    """Stored episodes (ends (E,) cumulative frame counts) with a frame in ``[start, stop)``."""
    first = int(np.searchsorted(ends, start, side="right"))
    last = int(np.searchsorted(ends, stop - 1, side="right"))
    return tuple(range(first, min(last, len(ends) - 1) + 1))


def describe_damage(path: Path, damage: Sequence[Damage], limit: int = 4) -> str:
    """One line naming the store, the damaged arrays/chunks and the episodes they hit."""
    episodes = sorted({e for d in damage for e in d.episodes})
    shown = "; ".join(d.describe() for d in damage[:limit])
    more = f"; and {len(damage) - limit} more bad chunks" if len(damage) > limit else ""
    return (
        f"store {path} is damaged: {len(damage)} bad chunk(s) in episode(s) "
        f"{short_list(episodes)}: {shown}{more}"
    )


def short_list(values: Sequence[int], limit: int = 20) -> str:
    """``[a, b, ...]`` showing at most ``limit`` of ``values``."""
    shown = ", ".join(map(str, values[:limit]))
    return f"[{shown}{', ...' if len(values) > limit else ''}]"


def scan_store_arrays(
    arrays: dict[str, zarr.Array],
    root: Path,
    rows: dict[str, int],
    owners: Callable[[str, int, int], tuple[int, ...]],
    deep: bool,
    legacy: bool,
) -> list[Damage]:
    """``Damage`` of every array of ``arrays`` (name -> array, rows to check in ``rows``).

    ``owners(name, start, stop)`` names the episodes of rows ``[start, stop)``. Values of
    ``CHEAP_VALUE_KEYS`` are always decoded and checked; every chunk is decoded when ``deep``.
    """
    damage: list[Damage] = []
    for name, arr in arrays.items():
        key = name.split("/")[-1]
        value_key = key if key in VALUE_RANGES else None
        decode = deep or key in CHEAP_VALUE_KEYS
        missing_ok = legacy and key == "goal_mask"
        for chunk, start, stop, problem in scan_array(
            arr, root, name, rows[name], value_key, decode, missing_ok
        ):
            damage.append(Damage(name, chunk, start, stop, problem, owners(name, start, stop)))
    return damage
