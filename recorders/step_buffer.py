"""A fixed-size block of batched steps, so recording writes in blocks and memory stays bounded.

Each step is pushed once for all parallel envs (one array copy per field, whatever `num_envs` is).
Env i's rows since its episode started (or since the last flush) are `take(i)`: a `StepBlock` of slices,
no copy.
"""

from __future__ import annotations

import numpy as np

from simreel.episode import StepBlock

__all__ = ["StepBuffer"]


class StepBuffer:
    """`capacity` rows × `num_envs` envs of named fields; rows are steps."""

    def __init__(self, capacity: int, num_envs: int) -> None:
        self.capacity = capacity
        self.num_envs = num_envs
        self.rows = 0
        self.start = np.zeros(num_envs, dtype=np.int64)
        self._arrays: dict[str, np.ndarray] = {}

    @property
    def full(self) -> bool:
        return self.rows == self.capacity

    def push(self, fields: dict[str, np.ndarray]) -> None:
        """Store one step: each field has a leading num_envs dimension."""
        r = self.rows
        for name, value in fields.items():
            buf = self._arrays.get(name)
            if buf is None:
                buf = np.empty((self.capacity, *value.shape), dtype=value.dtype)
                self._arrays[name] = buf
            buf[r] = value
        self.rows = r + 1

    def take(self, env: int) -> StepBlock:
        """Env `env`'s rows not yet taken, as views valid until the next `push` into those rows."""
        s, e = int(self.start[env]), self.rows
        self.start[env] = e
        return StepBlock({name: buf[s:e, env] for name, buf in self._arrays.items()}, e - s)

    def pending(self, env: int) -> int:
        return self.rows - int(self.start[env])

    def rewind(self) -> None:
        """Start over at row 0; every env's rows must have been taken."""
        self.rows = 0
        self.start[:] = 0
