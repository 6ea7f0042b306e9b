"""One episode's frames as stored (``EpisodeRecord``) and a synthetic one (``fake_episode``).

The store (:mod:`vla_gr.data.store`) appends records; ``FRAME_KEYS`` are its per-step arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vla_gr.data.integrity import VALUE_RANGES, value_problem

__all__ = ["FRAME_KEYS", "OPTIONAL_FRAME_KEYS", "EpisodeRecord", "fake_episode"]

FRAME_KEYS: tuple[str, ...] = ("rgb", "depth", "pose", "action", "goal_mask", "distractor_mask")
#: Frame keys that stores written before them lack (format 1 and early format 2); such a
#: store opens, and reading the key raises ``StoreError`` saying how to rebuild it.
OPTIONAL_FRAME_KEYS: tuple[str, ...] = ("distractor_mask",)


@dataclass
class EpisodeRecord:
    """One episode ready to be stored; T steps of H x W images.

    rgb (T, H, W, 3) uint8, depth (T, H, W, 1) float32, pose (T, 3) float32,
    action (T, 3) float32, goal_mask (T, H, W) bool, distractor_mask (T, H, W) bool (the
    pixels of the goal's same-category distractors; None only for episodes copied from a
    store that lacks it).
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
    distractor_mask: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.rgb = np.asarray(self.rgb, dtype=np.uint8)
        self.depth = np.asarray(self.depth, dtype=np.float32)
        self.pose = np.asarray(self.pose, dtype=np.float32)
        self.action = np.asarray(self.action, dtype=np.float32)
        self.goal_mask = np.asarray(self.goal_mask, dtype=bool)
        if self.distractor_mask is not None:
            self.distractor_mask = np.asarray(self.distractor_mask, dtype=bool)
        T = self.rgb.shape[0] if self.rgb.ndim == 4 else -1
        if T < 1 or self.rgb.shape[-1] != 3:
            raise ValueError(f"rgb must be (T, H, W, 3) with T >= 1, got {self.rgb.shape}")
        H, W = self.rgb.shape[1:3]
        expected = {
            "depth": (T, H, W, 1),
            "pose": (T, 3),
            "action": (T, 3),
            "goal_mask": (T, H, W),
            "distractor_mask": (T, H, W),
        }
        for key, shape in expected.items():
            if getattr(self, key) is None:
                continue
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
        """The per-step arrays by store key (without ``distractor_mask`` when it is None)."""
        return {k: getattr(self, k) for k in FRAME_KEYS if getattr(self, k) is not None}


def fake_episode(
    episode_index: int, length: int, image_size: int = 8, seed: int = 0
) -> EpisodeRecord:
    """A synthetic episode for smoke tests (like openpi's ``fake_obs``).

    Frame ``t`` is recognisable: ``pose[t] = (t, episode_index, 0)``,
    ``action[t, 0] = (t % 256) / 256`` and every rgb pixel of frame t equals ``t % 256``;
    the rest is seeded noise (``distractor_mask`` never overlaps ``goal_mask``).
    """
    rng = np.random.default_rng((seed, episode_index))
    T, S = length, image_size
    t = np.arange(T, dtype=np.float32)  # (T,)
    rgb = np.broadcast_to((np.arange(T) % 256).astype(np.uint8)[:, None, None, None], (T, S, S, 3))
    action = np.stack(
        [(t % 256) / 256, rng.uniform(-1, 1, T), np.where(t == T - 1, 1.0, -1.0)], axis=1
    )
    depth = rng.uniform(0.1, 5.0, (T, S, S, 1))
    goal_mask = rng.random((T, S, S)) > 0.8  # (T, S, S)
    distractor_mask = (rng.random((T, S, S)) > 0.8) & ~goal_mask  # (T, S, S)
    return EpisodeRecord(
        episode_index=episode_index,
        rgb=rgb.copy(),
        depth=depth,
        pose=np.stack([t, np.full(T, episode_index, np.float32), np.zeros(T, np.float32)], 1),
        action=action,
        goal_mask=goal_mask,
        distractor_mask=distractor_mask,
        instruction=f"find the red chair number {episode_index}",
        spec={"episode_id": episode_index, "scene_seed": int(seed)},
        metrics={"success": 1.0, "spl": 1.0},
    )
