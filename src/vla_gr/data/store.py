"""The episode store: expert episodes in one zarr group (layout of diffusion_policy's ReplayBuffer).

Layout (zarr format 3)::

    <root>/zarr.json            attrs: format, format_version, num_episodes, stats, info
    data/rgb        (N, H, W, 3) uint8     per step, chunked along N, compressed
    data/depth      (N, H, W, 1) float32   metres
    data/pose       (N, 3)       float32   (x, y, yaw) from the episode start
    data/action     (N, 3)       float32   the expert's noise-free label
    data/goal_mask  (N, H, W)    bool      instance segmentation == goal id
    meta/episode_ends   (E,) int64  cumulative frame counts
    meta/episode_index  (E,) int64  index of the episode in its split
    meta/instruction    (E,) str
    meta/spec           (E,) str    JSON of the episode spec
    meta/metrics        (E,) str    JSON of the episode's final metrics

Commit protocol: an episode's frames are appended first, then its ``meta`` entries, and
last the root attributes (``num_episodes`` and the updated ``stats``) in one atomic
metadata write. That write is the commit point: anything beyond ``num_episodes`` (or
beyond ``episode_ends[num_episodes - 1]`` frames) is the residue of an interrupted run.
Readers ignore it; ``repair()`` (run when a store is opened for appending) truncates it.

Integrity (format 2): every chunk ends in its CRC32C checksum and every chunk is written,
even when it holds only fill values. ``open`` checks that every chunk the committed
episodes need exists and matches its checksum, and that actions and poses are valid
(``vla_gr.data.integrity``); a damaged store is refused (``StoreError`` naming the store,
the arrays and the episodes) or, with ``on_corrupt="skip"``, opened without its damaged
episodes. Format-1 stores (no checksums) still open, with one warning: flipped or truncated
chunks can go unnoticed there; ``vla-gr store copy OLD NEW`` rewrites one with checksums.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec

from vla_gr.data.integrity import (
    VALUE_RANGES,
    Damage,
    describe_damage,
    episodes_of_rows,
    is_checksummed,
    scan_store_arrays,
    value_problem,
)
from vla_gr.data.normalize import compute_stats, merge_stats
from vla_gr.errors import UserError

log = logging.getLogger(__name__)

FORMAT_NAME = "vla_gr.episode_store"
FORMAT_VERSION = 2
#: Format versions this library reads; 1 has no chunk checksums.
READABLE_VERSIONS = (1, 2)
FRAME_KEYS: tuple[str, ...] = ("rgb", "depth", "pose", "action", "goal_mask")
META_KEYS: tuple[str, ...] = ("episode_ends", "episode_index", "instruction", "spec", "metrics")
#: Keys whose statistics are kept (and what ``stats`` holds for depth: one channel).
STATS_KEYS: tuple[str, ...] = ("action", "pose", "depth")
_MODES = ("r", "a")
ON_CORRUPT = ("error", "skip")
#: Arrays without which no episode can be located: damage there is never skippable.
_STRUCTURAL = ("meta/episode_ends", "meta/episode_index")
_warned_legacy: set[str] = set()


class StoreError(UserError, ValueError):
    """A store that is missing, malformed, inconsistent or damaged; the message names it."""


@dataclass
class EpisodeRecord:
    """One episode ready to be stored; T steps of H x W images.

    rgb (T, H, W, 3) uint8, depth (T, H, W, 1) float32, pose (T, 3) float32,
    action (T, 3) float32, goal_mask (T, H, W) bool.
    """

    episode_index: int
    rgb: np.ndarray
    depth: np.ndarray
    pose: np.ndarray
    action: np.ndarray
    goal_mask: np.ndarray
    instruction: str
    spec: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rgb = np.asarray(self.rgb, dtype=np.uint8)
        self.depth = np.asarray(self.depth, dtype=np.float32)
        self.pose = np.asarray(self.pose, dtype=np.float32)
        self.action = np.asarray(self.action, dtype=np.float32)
        self.goal_mask = np.asarray(self.goal_mask, dtype=bool)
        T = self.rgb.shape[0] if self.rgb.ndim == 4 else -1
        if T < 1 or self.rgb.shape[-1] != 3:
            raise ValueError(f"rgb must be (T, H, W, 3) with T >= 1, got {self.rgb.shape}")
        H, W = self.rgb.shape[1:3]
        expected = {
            "depth": (T, H, W, 1),
            "pose": (T, 3),
            "action": (T, 3),
            "goal_mask": (T, H, W),
        }
        for key, shape in expected.items():
            got = getattr(self, key).shape
            if got != shape:
                raise ValueError(
                    f"{key} must have shape {shape} (from rgb {self.rgb.shape}), got {got}"
                )
        for key in VALUE_RANGES:
            problem = value_problem(key, getattr(self, key))
            if problem is not None:
                raise ValueError(f"episode {self.episode_index}: {key} has {problem}")

    def __len__(self) -> int:
        return int(self.rgb.shape[0])

    def frames(self) -> dict[str, np.ndarray]:
        """The per-step arrays by store key."""
        return {k: getattr(self, k) for k in FRAME_KEYS}


def _frames_per_chunk(frame_shape: tuple[int, ...], itemsize: int, target_bytes: int) -> int:
    """Frames per chunk so one chunk holds about ``target_bytes`` (a power of two, 1..1024)."""
    frame_bytes = max(1, int(np.prod(frame_shape)) * itemsize)
    n = max(1, target_bytes // frame_bytes)
    return int(min(1024, 2 ** int(np.floor(np.log2(n)))))


def _frame_specs(image_size: tuple[int, int]) -> dict[str, tuple[tuple[int, ...], str]]:
    H, W = image_size
    return {
        "rgb": ((H, W, 3), "uint8"),
        "depth": ((H, W, 1), "float32"),
        "pose": ((3,), "float32"),
        "action": ((3,), "float32"),
        "goal_mask": ((H, W), "bool"),
    }


class EpisodeStore:
    """A zarr episode store; ``create`` a new one or ``open`` an existing one (validated).

    Only committed episodes are visible: ``num_episodes``, ``episode_ends`` and every
    accessor ignore the residue of an interrupted append. ``damage`` lists the bad chunks
    found on opening (``on_corrupt="report"``, used by ``verify_store``, keeps them
    without refusing or warning).
    """

    def __init__(
        self,
        path: str | Path,
        group: zarr.Group,
        mode: str,
        on_corrupt: str = "error",
        deep: bool = False,
    ) -> None:
        self.path = Path(path)
        self._group = group
        self.mode = mode
        self.damage: list[Damage] = []
        self._validate(on_corrupt, deep)

    # ------------------------------------------------------------------ construction
    @classmethod
    def create(
        cls,
        path: str | Path,
        image_size: int | tuple[int, int],
        overwrite: bool = False,
        info: Mapping | None = None,
        chunk_bytes: int = 1 << 20,
    ) -> EpisodeStore:
        """Create an empty store at ``path`` for ``image_size`` (S or (H, W)) images.

        Raises ``FileExistsError`` if ``path`` exists and ``overwrite`` is False.
        ``info`` (JSON-able) is kept in the root attributes (e.g. the collect config).
        The store is built under a temporary sibling name and renamed into place, so
        ``path`` is either absent or a complete, valid empty store (never half-created).
        """
        path = Path(path)
        if isinstance(image_size, int):
            image_size = (image_size, image_size)
        if len(image_size) != 2 or min(image_size) < 1:
            raise ValueError(
                f"image_size must be S or (H, W) with positive sizes, got {image_size}"
            )
        if path.exists():
            if not overwrite:
                raise FileExistsError(f"store {path} already exists (use overwrite=True)")
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        building = path.with_name(f".{path.name}.creating-{os.getpid()}")
        if building.exists():
            shutil.rmtree(building)
        group = zarr.open_group(str(building), mode="w-", zarr_format=3)
        data, meta = group.create_group("data"), group.create_group("meta")
        for key, (shape, dtype) in _frame_specs(tuple(image_size)).items():
            itemsize = np.dtype(dtype).itemsize
            shuffle = "bitshuffle" if itemsize > 1 else "shuffle"
            data.create_array(
                key,
                shape=(0, *shape),
                chunks=(_frames_per_chunk(shape, itemsize, chunk_bytes), *shape),
                dtype=dtype,
                compressors=[BloscCodec(cname="zstd", clevel=3, shuffle=shuffle), Crc32cCodec()],
            )
        checked = [ZstdCodec(level=3), Crc32cCodec()]
        meta.create_array(
            "episode_ends", shape=(0,), chunks=(4096,), dtype="int64", compressors=checked
        )
        meta.create_array(
            "episode_index", shape=(0,), chunks=(4096,), dtype="int64", compressors=checked
        )
        for key in ("instruction", "spec", "metrics"):
            meta.create_array(key, shape=(0,), chunks=(512,), dtype=str, compressors=checked)
        group.attrs.update(
            {
                "format": FORMAT_NAME,
                "format_version": FORMAT_VERSION,
                "image_size": list(image_size),
                "num_episodes": 0,
                "stats": {k: None for k in STATS_KEYS},
                "info": dict(info or {}),
            }
        )
        os.replace(building, path)
        log.info("created episode store %s (images %dx%d)", path, *image_size)
        return cls(path, zarr.open_group(str(path), mode="a", zarr_format=3), mode="a")

    @classmethod
    def open(
        cls, path: str | Path, mode: str = "r", on_corrupt: str = "error", deep: bool = False
    ) -> EpisodeStore:
        """Open and validate an existing store; ``mode`` 'r' (read) or 'a' (append).

        Every chunk the committed episodes need is checked (present, checksum, valid
        actions and poses; ``deep`` decodes and checks every chunk). A damaged store raises
        ``StoreError``; ``on_corrupt="skip"`` (read-only) opens it without the damaged
        episodes (``damaged_episodes``), listed in a warning. Opening for appending first
        truncates any residue of an interrupted append.
        """
        if mode not in _MODES:
            raise ValueError(f"mode={mode!r} is not valid; choose one of {list(_MODES)}")
        if on_corrupt not in ON_CORRUPT:
            raise ValueError(
                f"on_corrupt={on_corrupt!r} is not valid; choose one of {list(ON_CORRUPT)}"
            )
        if mode == "a" and on_corrupt == "skip":
            raise ValueError("on_corrupt='skip' opens read-only; use mode='r'")
        path = Path(path)
        if not (path / "zarr.json").is_file():
            raise StoreError(f"{path} is not an episode store (no zarr.json)")
        group = zarr.open_group(str(path), mode="r" if mode == "r" else "r+")
        store = cls(path, group, mode, on_corrupt=on_corrupt, deep=deep)
        if mode == "a" and store.has_uncommitted():
            store.repair()
        return store

    # ------------------------------------------------------------------ validation
    def _array(self, name: str) -> zarr.Array:
        try:
            arr = self._group[name]
        except KeyError:
            raise StoreError(f"store {self.path} is missing array '{name}'") from None
        if not isinstance(arr, zarr.Array):
            raise StoreError(f"store {self.path}: '{name}' is a group, expected an array")
        return arr.with_config({"write_empty_chunks": True})

    def _validate(self, on_corrupt: str = "error", deep: bool = False) -> None:
        attrs = self._group.attrs
        if attrs.get("format") != FORMAT_NAME:
            raise StoreError(
                f"store {self.path}: attribute format={attrs.get('format')!r}, "
                f"expected {FORMAT_NAME!r}"
            )
        version = attrs.get("format_version")
        if version not in READABLE_VERSIONS:
            raise StoreError(
                f"store {self.path}: format_version={version!r} is not supported "
                f"(this library reads {list(READABLE_VERSIONS)})"
            )
        self._data = {k: self._array(f"data/{k}") for k in FRAME_KEYS}
        self._meta = {k: self._array(f"meta/{k}") for k in META_KEYS}
        E = int(attrs.get("num_episodes", -1))
        if E < 0:
            raise StoreError(f"store {self.path}: attribute num_episodes is missing or negative")
        for key, arr in self._meta.items():
            if arr.shape[0] < E:
                raise StoreError(
                    f"store {self.path}: mismatched lengths: meta/{key} has "
                    f"{arr.shape[0]} entries but the store commits {E} episodes"
                )
        legacy = not is_checksummed(self._data["rgb"])
        structural = {k: self._group[k] for k in _STRUCTURAL}
        bad = self._scan(structural, {k: E for k in _STRUCTURAL}, None, deep, legacy)
        if bad:
            raise StoreError(
                f"{describe_damage(self.path, bad)}; no episode can be located without "
                "these arrays: collect the store again"
            )
        ends = np.asarray(self._meta["episode_ends"][:E], dtype=np.int64)  # (E,)
        if E and (ends[0] <= 0 or (np.diff(ends) <= 0).any()):
            raise StoreError(
                f"store {self.path}: meta/episode_ends is not strictly increasing "
                f"and positive: {ends.tolist()[:10]}"
            )
        N = int(ends[-1]) if E else 0
        for key, arr in self._data.items():
            if arr.shape[0] < N:
                raise StoreError(
                    f"store {self.path}: mismatched lengths: data/{key} has "
                    f"{arr.shape[0]} frames but meta/episode_ends needs {N}"
                )
        H, W = self.image_size
        for key, (shape, dtype) in _frame_specs((H, W)).items():
            arr = self._data[key]
            if tuple(arr.shape[1:]) != shape or np.dtype(arr.dtype) != np.dtype(dtype):
                raise StoreError(
                    f"store {self.path}: data/{key} has frames {tuple(arr.shape[1:])} "
                    f"{arr.dtype}, expected {shape} {dtype}"
                )
        self._E, self._N, self._ends = E, N, ends
        self._indices = set(np.asarray(self._meta["episode_index"][:E]).tolist())
        arrays = {n: a for n, a in self.arrays().items() if n not in _STRUCTURAL}
        rows = {name: (N if name.startswith("data/") else E) for name in arrays}
        self.damage = self._scan(arrays, rows, ends, deep, legacy)
        self._check_damage(on_corrupt)
        if legacy and str(self.path) not in _warned_legacy:
            _warned_legacy.add(str(self.path))
            log.warning(
                "store %s is format 1, written without chunk checksums: flipped or truncated "
                "chunks can go unnoticed (missing chunks and invalid actions are still "
                "caught); `vla-gr store copy %s NEW` rewrites it with checksums",
                self.path,
                self.path,
            )
        if self.has_uncommitted():
            log.warning(
                "store %s has uncommitted residue after %d episodes / %d frames "
                "(an interrupted append); it is ignored and truncated on the next append",
                self.path,
                E,
                N,
            )

    def _scan(self, arrays, rows, ends, deep: bool, legacy: bool) -> list[Damage]:
        """Damage of ``arrays`` (name -> array); frames map to episodes through ``ends``."""

        def owners(name: str, start: int, stop: int) -> tuple[int, ...]:
            if name.startswith("data/"):
                return episodes_of_rows(ends, start, stop)
            return tuple(range(start, stop))

        return scan_store_arrays(arrays, self.path, rows, owners, deep, legacy)

    def _check_damage(self, on_corrupt: str) -> None:
        """Refuse a damaged store, or (``skip``) warn once and hide its damaged episodes."""
        self._damaged = frozenset(e for d in self.damage for e in d.episodes)
        if not self.damage or on_corrupt == "report":
            return
        message = describe_damage(self.path, self.damage)
        if on_corrupt == "error":
            raise StoreError(
                f"{message}. Run `vla-gr store verify {self.path}` for a full report, or skip "
                "the damaged episodes with on_corrupt='skip' (training.on_corrupt=skip)"
            )
        log.warning("%s; skipping those episodes", message)

    @property
    def damaged_episodes(self) -> list[int]:
        """Sorted stored episodes that a bad chunk hits (empty for a healthy store)."""
        return sorted(self._damaged)

    def _require_intact(self, e: int) -> None:
        if e in self._damaged:
            raise StoreError(
                f"store {self.path}: episode {e} is damaged "
                f"({'; '.join(d.describe() for d in self.damage if e in d.episodes)})"
            )

    def has_uncommitted(self) -> bool:
        """True when some array extends beyond the committed episodes (an interrupted append)."""
        return any(a.shape[0] > self._N for a in self._data.values()) or any(
            a.shape[0] > self._E for a in self._meta.values()
        )

    def repair(self) -> None:
        """Truncate every array to the committed episodes."""
        self._require_writable()
        for arr in self._data.values():
            if arr.shape[0] > self._N:
                arr.resize((self._N, *arr.shape[1:]))
        for arr in self._meta.values():
            if arr.shape[0] > self._E:
                arr.resize((self._E,))
        log.info(
            "repaired store %s: truncated to %d episodes / %d frames", self.path, self._E, self._N
        )

    def _require_writable(self) -> None:
        if self.mode != "a":
            raise StoreError(f"store {self.path} is open read-only (mode='r'); use mode='a'")

    # ------------------------------------------------------------------ reading
    @property
    def image_size(self) -> tuple[int, int]:
        H, W = self._group.attrs["image_size"]
        return int(H), int(W)

    @property
    def num_episodes(self) -> int:
        return self._E

    @property
    def num_frames(self) -> int:
        return self._N

    @property
    def episode_ends(self) -> np.ndarray:
        """(E,) int64 cumulative frame counts of the committed episodes."""
        return self._ends.copy()

    @property
    def episode_lengths(self) -> np.ndarray:
        """(E,) int64 number of steps of each episode."""
        return np.diff(self._ends, prepend=0)

    @property
    def episode_indices(self) -> np.ndarray:
        """(E,) int64 index in its split of each stored episode."""
        return np.asarray(self._meta["episode_index"][: self._E], dtype=np.int64)

    @property
    def stats(self) -> dict:
        """Normalisation statistics (see ``normalize.compute_stats``) per key of ``STATS_KEYS``."""
        return dict(self._group.attrs["stats"])

    @property
    def info(self) -> dict:
        return dict(self._group.attrs.get("info", {}))

    def arrays(self) -> dict[str, zarr.Array]:
        """Every array by its name in the store: ``data/rgb`` ... ``meta/metrics``."""
        named = {f"data/{k}": a for k, a in self._data.items()}
        return named | {f"meta/{k}": a for k, a in self._meta.items()}

    def data_array(self, key: str) -> zarr.Array:
        """The raw zarr array ``data/<key>``; only its first ``num_frames`` rows are committed."""
        if key not in self._data:
            raise KeyError(f"unknown frame key {key!r}; choose one of {list(FRAME_KEYS)}")
        return self._data[key]

    def episode_slice(self, e: int) -> slice:
        """Frame range of stored episode ``e`` (0 <= e < num_episodes)."""
        if not 0 <= e < self._E:
            raise IndexError(f"episode {e} out of range [0, {self._E})")
        start = int(self._ends[e - 1]) if e > 0 else 0
        return slice(start, int(self._ends[e]))

    def episode(self, e: int, keys=FRAME_KEYS) -> dict[str, np.ndarray]:
        """Frames of stored episode ``e``: each key -> (T, ...) array."""
        sl = self.episode_slice(e)
        self._require_intact(e)
        return {k: self.data_array(k)[sl] for k in keys}

    def _meta_str(self, key: str, e: int) -> str:
        if not 0 <= e < self._E:
            raise IndexError(f"episode {e} out of range [0, {self._E})")
        self._require_intact(e)
        return str(self._meta[key][e])

    def instruction(self, e: int) -> str:
        return self._meta_str("instruction", e)

    def instructions(self) -> list[str]:
        """All committed instructions, in store order ("" for damaged episodes)."""
        if self._damaged:
            return ["" if e in self._damaged else self.instruction(e) for e in range(self._E)]
        return [str(s) for s in self._meta["instruction"][: self._E]] if self._E else []

    def spec(self, e: int) -> dict:
        return json.loads(self._meta_str("spec", e))

    def metrics(self, e: int) -> dict:
        return json.loads(self._meta_str("metrics", e))

    # ------------------------------------------------------------------ writing
    def append(self, record: EpisodeRecord) -> bool:
        """Append and commit one episode; returns False (and writes nothing) if its
        ``episode_index`` is already stored."""
        self._require_writable()
        if record.rgb.shape[1:3] != self.image_size:
            raise ValueError(
                f"record images are {record.rgb.shape[1:3]}, store holds {self.image_size}"
            )
        if record.episode_index in self._indices:
            log.info("episode %d is already stored; skipped", record.episode_index)
            return False
        if self.has_uncommitted():
            self.repair()
        T = len(record)
        # 1) frames, 2) per-episode meta, 3) the commit: num_episodes + stats in one write.
        for key, values in record.frames().items():
            self._data[key].append(values)
        self._meta["episode_index"].append(np.array([record.episode_index], dtype=np.int64))
        self._meta["instruction"].append(np.array([record.instruction], dtype=str))
        self._meta["spec"].append(np.array([json.dumps(record.spec, sort_keys=True)], dtype=str))
        self._meta["metrics"].append(
            np.array([json.dumps(record.metrics, sort_keys=True)], dtype=str)
        )
        self._meta["episode_ends"].append(np.array([self._N + T], dtype=np.int64))
        stats = self.stats
        new_stats = {
            "action": merge_stats(stats.get("action"), compute_stats(record.action)),
            "pose": merge_stats(stats.get("pose"), compute_stats(record.pose)),
            "depth": merge_stats(stats.get("depth"), compute_stats(record.depth.reshape(-1, 1))),
        }
        self._commit(self._E + 1, new_stats)
        self._E, self._N = self._E + 1, self._N + T
        self._ends = np.append(self._ends, self._N)
        self._indices.add(record.episode_index)
        return True

    def _commit(self, num_episodes: int, stats: dict) -> None:
        """The commit point: one atomic write of the root metadata."""
        self._group.attrs.update({"num_episodes": num_episodes, "stats": stats})

    def __repr__(self) -> str:
        return (
            f"EpisodeStore({str(self.path)!r}, episodes={self._E}, frames={self._N}, "
            f"image_size={self.image_size}, mode={self.mode!r})"
        )


def fake_episode(
    episode_index: int, length: int, image_size: int = 8, seed: int = 0
) -> EpisodeRecord:
    """A synthetic episode for smoke tests (like openpi's ``fake_obs``).

    Frame ``t`` is recognisable: ``pose[t] = (t, episode_index, 0)``,
    ``action[t, 0] = (t % 256) / 256`` and every rgb pixel of frame t equals ``t % 256``;
    the rest is seeded noise.
    """
    rng = np.random.default_rng((seed, episode_index))
    T, S = length, image_size
    t = np.arange(T, dtype=np.float32)  # (T,)
    rgb = np.broadcast_to((np.arange(T) % 256).astype(np.uint8)[:, None, None, None], (T, S, S, 3))
    action = np.stack(
        [(t % 256) / 256, rng.uniform(-1, 1, T), np.where(t == T - 1, 1.0, -1.0)], axis=1
    )
    return EpisodeRecord(
        episode_index=episode_index,
        rgb=rgb.copy(),
        depth=rng.uniform(0.1, 5.0, (T, S, S, 1)),
        pose=np.stack([t, np.full(T, episode_index, np.float32), np.zeros(T, np.float32)], 1),
        action=action,
        goal_mask=rng.random((T, S, S)) > 0.8,
        instruction=f"find the red chair number {episode_index}",
        spec={"episode_id": episode_index, "scene_seed": int(seed)},
        metrics={"success": 1.0, "spl": 1.0},
    )
