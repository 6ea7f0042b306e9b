"""The observation's ``instruction`` space, whose batched reads from shared memory stay live."""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np
from gymnasium.vector.utils import read_from_shared_memory


class InstructionSpace(gym.spaces.Text):
    """The ``instruction`` Text space; batched reads from shared memory stay live.

    Gymnasium's ``AsyncVectorEnv`` reads its shared observation buffer once, at
    construction; arrays are views and update in place, but a Text read is a tuple of
    strings frozen at that moment (every later batch would repeat it). For this subclass
    the read returns a :class:`LiveTextBatch` that decodes the buffer on access.
    """


class LiveTextBatch(Sequence):
    """Strings (n,) decoded on access from a shared int32 buffer (n, max_length)."""

    def __init__(self, space: gym.spaces.Text, shared_memory, n: int) -> None:
        self._space, self._shared, self._n = space, shared_memory, n

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, index):
        if isinstance(index, slice):
            return tuple(self[i] for i in range(*index.indices(self._n)))
        codes = np.frombuffer(self._shared.get_obj(), dtype=np.int32)
        codes = codes.reshape(self._n, self._space.max_length)[index]  # (max_length,)
        chars, size = self._space.character_list, len(self._space.character_set)
        return "".join(chars[c] for c in codes if c < size)

    def __eq__(self, other) -> bool:
        return isinstance(other, Sequence) and tuple(self) == tuple(other)

    def __deepcopy__(self, memo) -> tuple[str, ...]:
        return tuple(self)  # AsyncVectorEnv(copy=True) hands out a snapshot

    def __repr__(self) -> str:
        return repr(tuple(self))


@read_from_shared_memory.register(InstructionSpace)
def _read_instructions(space: InstructionSpace, shared_memory, n: int = 1) -> LiveTextBatch:
    return LiveTextBatch(space, shared_memory, n)
