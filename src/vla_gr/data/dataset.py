"""Training windows over an episode store (diffusion_policy's SequenceSampler, LeRobot's padding).

Every step ``t`` of every selected episode is one sample: the observation history
``t - n_obs_steps + 1 .. t`` and the action chunk ``t .. t + horizon - 1``. Indices that
fall outside the episode repeat its first (history) or last (chunk) frame, and
``obs_is_pad`` / ``action_is_pad`` say which entries are such copies.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from vla_gr.data.normalize import MinMaxNormalizer, normalizers_from_stats
from vla_gr.data.store import EpisodeStore

log = logging.getLogger(__name__)

_SPLITS = ("train", "val", "all")


def split_episodes(
    num_episodes: int, val_ratio: float, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic episode-level split: (train ids (E_t,), val ids (E_v,)), each sorted.

    ``round(num_episodes * val_ratio)`` episodes go to val, but at least one when
    ``val_ratio > 0`` and there are two or more episodes, and never all of them.
    """
    if num_episodes < 0:
        raise ValueError(f"num_episodes={num_episodes} must be >= 0")
    if not 0.0 <= val_ratio < 1.0:
        raise ValueError(f"val_ratio={val_ratio} must be in [0, 1)")
    n_val = int(round(num_episodes * val_ratio))
    if val_ratio > 0 and num_episodes >= 2:
        n_val = min(max(n_val, 1), num_episodes - 1)
    perm = np.random.default_rng(seed).permutation(num_episodes)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def window_indices(
    t: int, length: int, n_obs_steps: int, horizon: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Within-episode indices for the sample at step ``t`` of an episode of ``length`` steps.

    Returns obs indices (n_obs_steps,), obs pad mask (n_obs_steps,), action indices
    (horizon,) and action pad mask (horizon,); out-of-episode indices are clamped to
    the first / last step.
    """
    if not 0 <= t < length:
        raise ValueError(f"t={t} must be in [0, length={length})")
    obs = np.arange(t - n_obs_steps + 1, t + 1)  # (n_obs_steps,)
    act = np.arange(t, t + horizon)  # (horizon,)
    return (
        np.clip(obs, 0, length - 1),
        obs < 0,
        np.clip(act, 0, length - 1),
        act > length - 1,
    )


class EpisodeWindowDataset(Dataset):
    """Windows of (observation history, action chunk) from an ``EpisodeStore``.

    Each item is a dict:
      ``rgb`` (T, 3, H, W) float32 in [0, 1] (uint8 with ``rgb_uint8=True``),
      ``depth`` (T, 1, H, W) float32 metres, ``pose`` (T, 3) float32,
      ``goal_mask`` (T, 1, H, W) bool, ``distractor_mask`` (T, 1, H, W) bool (when the
      store holds it), ``obs_is_pad`` (T,) bool,
      ``action`` (horizon, 3) float32, ``action_is_pad`` (horizon,) bool,
      ``instruction`` str, ``episode`` int (store row), ``step`` int (t),
    with T = ``n_obs_steps``. With ``normalize=True`` pose and action are mapped to
    [-1, 1] by ``self.normalizers`` (min/max stored with the data). ``in_memory=False``
    reads whole episodes from the store on demand and keeps the last ``cache_episodes``.
    A store opened with ``on_corrupt="skip"`` contributes only its intact episodes (the
    split is drawn over all episodes first, so it does not move when some are damaged).

    In memory, boolean frames (the masks) are held bit-packed, 8 pixels a byte, and unpacked
    per item: lossless, an eighth of the bytes. ``depth_float16=True`` also holds depth in
    float16 (half the bytes; relative rounding error <= 2**-11, 2.4 mm at 5 m); items are
    float32 either way.
    """

    def __init__(
        self,
        path: str | Path | EpisodeStore,
        n_obs_steps: int = 2,
        horizon: int = 16,
        split: str = "train",
        val_ratio: float = 0.1,
        seed: int = 0,
        episodes: Sequence[int] | None = None,
        in_memory: bool = True,
        cache_episodes: int = 4,
        rgb_uint8: bool = False,
        normalize: bool = False,
        on_corrupt: str = "error",
        depth_float16: bool = False,
    ) -> None:
        if n_obs_steps < 1:
            raise ValueError(f"n_obs_steps={n_obs_steps} must be >= 1")
        if horizon < 1:
            raise ValueError(f"horizon={horizon} must be >= 1")
        if split not in _SPLITS:
            raise ValueError(f"split={split!r} is not valid; choose one of {list(_SPLITS)}")
        store = (
            path
            if isinstance(path, EpisodeStore)
            else EpisodeStore.open(path, mode="r", on_corrupt=on_corrupt)
        )
        self.store = store
        self.n_obs_steps, self.horizon = n_obs_steps, horizon
        self.rgb_uint8, self.normalize = rgb_uint8, normalize
        E = store.num_episodes
        if episodes is None:
            train_ids, val_ids = split_episodes(E, val_ratio, seed)
            ids = {"train": train_ids, "val": val_ids, "all": np.arange(E)}[split]
        else:
            ids = np.asarray(sorted(set(int(e) for e in episodes)), dtype=np.int64)
            bad = ids[(ids < 0) | (ids >= E)]
            if bad.size:
                raise ValueError(f"episodes {bad.tolist()} out of range [0, {E})")
        ids = np.asarray(ids, dtype=np.int64)
        damaged = np.isin(ids, store.damaged_episodes)
        if damaged.any():
            log.warning(
                "dataset %s split=%s: left out damaged episodes %s",
                store.path,
                split,
                ids[damaged].tolist(),
            )
        self.episode_ids = ids[~damaged]  # (E_sel,)
        lengths = store.episode_lengths[self.episode_ids]  # (E_sel,)
        self._lengths = lengths
        # Global (store) frame offset of each selected episode, and of the local copy.
        self._store_starts = store.episode_ends[self.episode_ids] - lengths  # (E_sel,)
        self._local_starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        # One sample per step: (selected episode, t).
        self._sample_episode = np.repeat(np.arange(len(lengths)), lengths)  # (S,)
        self._sample_t = (
            np.concatenate([np.arange(n) for n in lengths])
            if len(lengths)
            else (np.zeros(0, dtype=np.int64))
        )  # (S,)
        self.in_memory = in_memory
        self.depth_float16 = depth_float16
        self.cache_episodes = max(1, int(cache_episodes))
        self._cache: OrderedDict[int, dict[str, np.ndarray]] = OrderedDict()
        # Width of the last axis of each boolean frame key (held bit-packed in memory).
        self._packed_width = {
            k: int(store.data_array(k).shape[-1])
            for k in store.frame_keys
            if store.data_array(k).dtype == bool
        }
        if in_memory:
            self._frames = {k: self._load_selected(k) for k in store.frame_keys}
        self._instructions = store.instructions()
        stats = store.stats
        self.normalizers: dict[str, MinMaxNormalizer] = (
            normalizers_from_stats(stats) if stats.get("action") is not None else {}
        )
        log.info(
            "dataset %s split=%s: %d episodes, %d windows",
            store.path,
            split,
            len(self.episode_ids),
            len(self),
        )

    def _load_selected(self, key: str) -> np.ndarray:
        """Concatenated frames (sum of lengths, ...) of the selected episodes, in their
        in-memory form: booleans bit-packed along the last axis, depth in float16 when asked."""
        arr = self.store.data_array(key)
        shape, dtype = arr.shape[1:], arr.dtype
        if key in self._packed_width:
            shape, dtype = (*shape[:-1], (shape[-1] + 7) // 8), np.uint8
        elif key == "depth" and self.depth_float16:
            dtype = np.float16
        # Filled in place: the peak is the final array, not the parts plus their concatenation.
        out = np.empty((int(self._lengths.sum()), *shape), dtype=dtype)  # (sum of lengths, ...)
        for s, n, at in zip(self._store_starts, self._lengths, self._local_starts):
            part = arr[s : s + n]  # (n, ...)
            out[at : at + n] = np.packbits(part, axis=-1) if key in self._packed_width else part
        return out

    def memory_bytes(self) -> int:
        """Bytes held by the in-memory frames (0 when frames are read on demand)."""
        return sum(a.nbytes for a in self._frames.values()) if self.in_memory else 0

    def _episode_frames(self, j: int) -> dict[str, np.ndarray]:
        """All frames of selected episode ``j`` read from the store, through a small LRU."""
        frames = self._cache.get(j)
        if frames is None:
            start, n = int(self._store_starts[j]), int(self._lengths[j])
            frames = {k: self.store.data_array(k)[start : start + n] for k in self.store.frame_keys}
            self._cache[j] = frames
            while len(self._cache) > self.cache_episodes:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(j)
        return frames

    def _gather(self, key: str, j: int, idx: np.ndarray) -> np.ndarray:
        """Frames ``idx`` (K,) within selected episode ``j`` -> (K, ...)."""
        if not self.in_memory:
            return self._episode_frames(j)[key][idx]
        frames = self._frames[key][int(self._local_starts[j]) + idx]  # (K, ...)
        if key in self._packed_width:
            width = self._packed_width[key]
            return np.unpackbits(frames, axis=-1, count=width).astype(bool)  # (K, ..., W)
        return frames.astype(np.float32) if frames.dtype == np.float16 else frames

    def __len__(self) -> int:
        return int(self._sample_episode.shape[0])

    def __getitem__(self, i: int) -> dict:
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} windows")
        i = i % len(self)
        j, t = int(self._sample_episode[i]), int(self._sample_t[i])
        obs_idx, obs_pad, act_idx, act_pad = window_indices(
            t, int(self._lengths[j]), self.n_obs_steps, self.horizon
        )
        rgb = torch.from_numpy(self._gather("rgb", j, obs_idx)).permute(0, 3, 1, 2)  # (T, 3, H, W)
        if not self.rgb_uint8:
            rgb = rgb.float() / 255.0
        depth = torch.from_numpy(self._gather("depth", j, obs_idx)).permute(0, 3, 1, 2)  # (T,1,H,W)
        goal_mask = torch.from_numpy(self._gather("goal_mask", j, obs_idx))[:, None]  # (T,1,H,W)
        pose = torch.from_numpy(self._gather("pose", j, obs_idx))  # (T, 3)
        action = torch.from_numpy(self._gather("action", j, act_idx))  # (horizon, 3)
        if self.normalize:
            pose = self.normalizers["pose"].normalize(pose)
            action = self.normalizers["action"].normalize(action)
        e = int(self.episode_ids[j])
        item = {
            "rgb": rgb.contiguous(),
            "depth": depth.contiguous(),
            "pose": pose,
            "goal_mask": goal_mask,
            "obs_is_pad": torch.from_numpy(obs_pad),
            "action": action,
            "action_is_pad": torch.from_numpy(act_pad),
            "instruction": self._instructions[e],
            "episode": e,
            "step": t,
        }
        if "distractor_mask" in self.store.frame_keys:
            distractors = self._gather("distractor_mask", j, obs_idx)  # (T, H, W)
            item["distractor_mask"] = torch.from_numpy(distractors)[:, None]  # (T, 1, H, W)
        return item

    def get_normalizers(self) -> dict[str, MinMaxNormalizer]:
        """Per-key normalisers (``action``, ``pose``) from the store's statistics."""
        if not self.normalizers:
            raise ValueError(f"store {self.store.path} has no statistics (is it empty?)")
        return dict(self.normalizers)
