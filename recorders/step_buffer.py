"""A fixed-size block of batched steps, so recording writes in blocks and memory stays bounded.

Each step is pushed once for all parallel envs: its arrays are copied into the block (one copy per field,
whatever `num_envs` is), and what is cheaper to capture now and convert later (by a `RowSource`: Python lists of
scalars, the physics engine's packed state bytes) is kept as captured and turned into rows for all the block's
steps at once, when the rows are first taken. Right after a physics step the CPU's caches are cold and every
numpy call costs several times its usual price; once per block the same conversions run on warm caches, or in the
writer process, which gets the captures with the block (`take(defer=True)`).
Env i's rows since its episode started (or since the last flush) are `take(i)`: a `StepBlock` of slices,
no copy.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from simreel.model.blocks import StepBlock

__all__ = ["StepBuffer", "RowSource", "FieldsChanged"]


RowSource = Callable[[list[Any]], dict[str, np.ndarray]]
"""Turns the captures of k steps (in step order) into those steps' fields, each (k, num_envs, ...): a
`simreel.sim.step_rows` class, which names its fields (`names`) and pickles."""


class FieldsChanged(ValueError):
    """A step that does not bring the fields the buffer's first step brought (as arrays or through its captures'
    sources): a field missing from it would keep the rows of an earlier block, or none at all (`StepBuffer.push`)."""

    def __init__(self, missing: list[str], new: list[str]) -> None:
        self.missing, self.new = missing, new
        differences = [f"{what} {', '.join(names)}" for what, names in (("missing", missing), ("new", new)) if names]
        super().__init__(f"a step whose fields are not the first step's: {'; '.join(differences)}")


class StepBuffer:
    """`capacity` rows × `num_envs` envs of named fields; rows are steps. Every step brings the same fields, as the
    first step pushed did (`FieldsChanged` otherwise)."""

    def __init__(self, capacity: int, num_envs: int) -> None:
        self.capacity = capacity
        self.num_envs = num_envs
        self.rows = 0
        self.start = np.zeros(num_envs, dtype=np.int64)
        self._arrays: dict[str, np.ndarray] = {}
        self._captured: dict[RowSource, tuple[list[int], list[Any]]] = {}
        """Per source, the rows it captured and not yet converted, and the captures (its own objects)."""
        self._names: frozenset[str] | None = None
        """The fields every step brings: those of the first step pushed (`_check_fields`)."""
        self._arrays_brought: dict[int, int] = {}
        """Per number of captures a step brings, how many arrays such a step brought when its fields were checked."""

    @property
    def full(self) -> bool:
        return self.rows == self.capacity

    def push(self, fields: dict[str, np.ndarray], captures: Sequence[tuple[RowSource, Any]] = ()) -> None:
        """Store one step: each field has a leading num_envs dimension; each capture becomes its source's fields
        for this row when the rows are taken (a capture must not change after it is pushed). `FieldsChanged`, and the
        step is not stored, where its fields (its arrays' and its sources') are not the first step's."""
        if self._arrays_brought.get(len(captures)) != len(fields):
            self._check_fields(fields, captures)
        r, arrays = self.rows, self._arrays
        for name, value in fields.items():
            buf = arrays.get(name)
            if buf is None:  # the first step, or a field it did not bring (then not one of `_names`: refused)
                if name not in self._names:
                    self._check_fields(fields, captures)
                buf = self._row_buffer(name, value)
            buf[r] = value
        captured = self._captured
        for source, capture in captures:
            entry = captured.get(source)
            if entry is None:
                entry = captured[source] = ([], [])
            entry[0].append(r)
            entry[1].append(capture)
        self.rows = r + 1

    def _check_fields(self, fields: dict[str, np.ndarray], captures: Sequence[tuple[RowSource, Any]]) -> None:
        """Check a step's fields against the first step's, in full: run for the first step with each number of
        captures and its count of arrays (a count that matches one checked is the same fields: a new field could
        only keep the count by replacing one, and a field without rows yet is checked before they are made)."""
        names = frozenset(fields).union(*(source.names for source, _ in captures))
        if self._names is None:
            self._names = names
        elif names != self._names:
            raise FieldsChanged(sorted(self._names - names), sorted(names - self._names))
        self._arrays_brought[len(captures)] = len(fields)

    def _row_buffer(self, name: str, row: np.ndarray) -> np.ndarray:
        buf = self._arrays.get(name)
        if buf is None:
            buf = self._arrays[name] = np.empty((self.capacity, *row.shape), dtype=row.dtype)
        return buf

    def _convert(self) -> None:
        """Turn every capture held into its rows (all sources at once: one conversion per block, not per step)."""
        for source, (rows, held) in self._captured.items():
            at = slice(rows[0], rows[-1] + 1) if rows[-1] - rows[0] == len(rows) - 1 else rows
            for name, value in source(held).items():
                self._row_buffer(name, value[0])[at] = value
        self._captured.clear()

    def take(self, env: int, *, defer: bool = False) -> StepBlock:
        """Env `env`'s rows not yet taken, as views valid until the next `push` into those rows. `defer`: leave the
        captures in the block, unconverted (`StepBlock.captured`, for a writer process to convert), where there is
        one env and each source captured every row taken (else they are converted here)."""
        s, e = int(self.start[env]), self.rows
        self.start[env] = e
        captured: tuple[tuple[RowSource, list[Any], int], ...] = ()
        if self._captured:
            if defer and self.num_envs == 1 and all(len(rows) == e - s for rows, _ in self._captured.values()):
                captured = tuple((source, held, env) for source, (_, held) in self._captured.items())
                self._captured.clear()
            else:
                self._convert()
        made = {name for source, _, _ in captured for name in source.names}
        return StepBlock({name: buf[s:e, env] for name, buf in self._arrays.items() if name not in made}, e - s, captured)

    def pending(self, env: int) -> int:
        return self.rows - int(self.start[env])

    def rewind(self) -> None:
        """Start over at row 0; every env's rows must have been taken."""
        self.rows = 0
        self.start[:] = 0
        self._captured.clear()
