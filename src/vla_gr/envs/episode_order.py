"""The order in which an env runs its episodes: what a seed means, as in gymnasium.

A seed ``s`` fixes one order of an env's ``count`` episodes (a split's, or an episodes file's).
Positions ``e * count`` to ``(e + 1) * count - 1`` (epoch ``e``) hold every episode once, in an
order drawn from ``(s, e)``. The env at place ``i`` of ``n`` sub-envs of a vector env runs the
positions ``i, i + n, i + 2n, ...`` of that order: sub-envs share the order and never repeat one
another, and stepping in lockstep they run every episode once before any twice. A lone env is
place 0 of 1. Gymnasium seeds sub-env ``i`` with ``s + i``, so place ``i`` takes ``s`` back as
its order's seed.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

#: Orders of at most this many episodes are drawn as full permutations; longer ones (a split of
#: millions) as a seeded Feistel bijection, which needs no memory.
PERMUTATION_LIMIT = 1 << 20
FEISTEL_ROUNDS = 4
_SEED_MODULUS = 1 << 64  # seeds are taken modulo this (SeedSequence needs them >= 0)


def _mix(x: int) -> int:
    """SplitMix64's finaliser: a 64-bit integer hash."""
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) % _SEED_MODULUS
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) % _SEED_MODULUS
    return x ^ (x >> 31)


def _feistel(offset: int, count: int, keys: list[int]) -> int:
    """A bijection of [0, count) keyed by ``keys``: a balanced Feistel network on the smallest
    even number of bits that holds ``count``, walked until it lands below ``count``."""
    half = ((count - 1).bit_length() + 1) // 2 or 1
    mask = (1 << half) - 1
    x = offset
    while True:
        left, right = x >> half, x & mask
        for key in keys:
            left, right = right, left ^ (_mix(right ^ key) & mask)
        x = (left << half) | right
        if x < count:
            return x


@functools.lru_cache(maxsize=8)
def _permutation(seed: int, epoch: int, count: int) -> np.ndarray:
    """The order (count,) of epoch ``epoch`` under ``seed``."""
    return np.random.default_rng([seed, epoch]).permutation(count)


def episode_at(seed: int, position: int, count: int) -> int:
    """The episode index at ``position`` (>= 0) of the order that ``seed`` gives ``count``
    episodes; each epoch of ``count`` positions holds every index once."""
    if count < 1:
        raise ValueError(f"count={count} must be >= 1")
    if position < 0:
        raise ValueError(f"position={position} must be >= 0")
    seed = int(seed) % _SEED_MODULUS
    epoch, offset = divmod(int(position), int(count))
    if count <= PERMUTATION_LIMIT:
        return int(_permutation(seed, epoch, int(count))[offset])
    keys = np.random.default_rng([seed, epoch]).integers(0, 1 << 62, FEISTEL_ROUNDS).tolist()
    return _feistel(offset, int(count), keys)


@dataclass
class EpisodeOrder:
    """Where one env stands in its seeded order: place ``index`` of ``places`` sub-envs.

    ``seed(s)`` restarts the order (the seed gymnasium gives place ``i`` is ``s + i``);
    ``next()`` returns the next episode index of this place. Before any seed, the order's seed
    is drawn from the operating system's entropy at the first ``next()``.
    """

    count: int
    index: int = 0
    places: int = 1
    base: int | None = None  # the order's seed; None until seeded or first used
    position: int = 0  # how many episodes this place has taken from the order

    @classmethod
    def for_sub_env(cls, count: int, sub_env) -> EpisodeOrder:
        """The order of place ``sub_env[0]`` of ``sub_env[1]``; ValueError quoting ``sub_env``
        unless it is two ints with 0 <= place < count."""
        try:
            index, places = (int(v) for v in sub_env)
        except (TypeError, ValueError):
            raise ValueError(f"sub_env={sub_env!r} must be (place, count)") from None
        if not 0 <= index < places:
            raise ValueError(f"sub_env={sub_env!r} must satisfy 0 <= place < count")
        return cls(int(count), index, places)

    def seed(self, seed: int) -> None:
        """Restart at the first position of the order of the vector seed ``seed - index``."""
        self.base = (int(seed) - self.index) % _SEED_MODULUS
        self.position = 0

    def next(self) -> int:
        """The next episode index of this place (and advance)."""
        if self.base is None:
            self.base = int(np.random.SeedSequence().entropy) % _SEED_MODULUS
        index = episode_at(self.base, self.index + self.places * self.position, self.count)
        self.position += 1
        return index


def episode_noise_rng(index: int, seed: int | None = None) -> np.random.Generator:
    """The generator of episode ``index``'s robustness noise under ``seed`` (None counts as 0).

    Drawn from ``SeedSequence([index, seed])``; with seed 0 that is ``SeedSequence(index)``,
    the generator ``reset(seed=index)`` gave before seeds ordered episodes, so figures measured
    with noise then are reproduced by ``reset(options={"episode": index})``.
    """
    seed = 0 if seed is None else int(seed) % _SEED_MODULUS
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(index), seed])))
