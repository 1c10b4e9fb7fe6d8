"""The rows a training set reads, a block at a time: each process (the main one, every DataLoader worker) opens
its own readers on first use and keeps the blocks it read last (`BlockCache`, bounded in bytes), so memory stays flat
however many episodes the set holds and a window read twice (overlapping samples) is read once."""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import numpy as np

from simreel.formats import open_reader
from simreel.formats.base import EpisodeReader, EpisodeRows, block_rows
from simreel.model.fields import FieldSpec

__all__ = ["BlockCache", "OPEN_EPISODES"]

OPEN_EPISODES = 16
"""Episodes a process keeps open at once (the ones read last): memory stays flat however many the set holds."""


class BlockCache:
    """The chosen `fields` of episodes, read in blocks of `rows` steps (None: `block_rows` of the fields, ~4 MiB)
    through readers this process opened. Rows are given in each field's own numbering: a per-state field's row r is
    the state after r steps (row 0 after the reset), a per-step field's row r is step r."""

    def __init__(self, fields: Sequence[FieldSpec], *, rows: int | None = None, max_bytes: int = 64 << 20) -> None:
        self.fields = list(fields)
        self.names = [f.name for f in self.fields]
        self.rows = rows or block_rows(self.fields)
        self.max_bytes = max_bytes
        self._no_handles()

    def _no_handles(self) -> None:
        """Start with no reader open and no block kept, in this process."""
        self._pid = os.getpid()
        self._readers: dict[str, EpisodeReader] = {}
        self._episodes: OrderedDict[tuple[str, int], EpisodeRows] = OrderedDict()
        self._blocks: OrderedDict[tuple[str, int, int], dict[str, np.ndarray]] = OrderedDict()
        self._held = 0

    def _rows_of(self, path: str, index: int) -> EpisodeRows:
        if os.getpid() != self._pid:  # a forked worker: its parent's handles are not its own
            self._no_handles()
        rows = self._episodes.get((path, index))
        if rows is not None:
            self._episodes.move_to_end((path, index))
            return rows
        reader = self._readers.get(path)
        if reader is None:
            reader = self._readers[path] = open_reader(path)
        rows = self._episodes[(path, index)] = reader.open_episode(index)
        while len(self._episodes) > OPEN_EPISODES:  # each holds its datasets' handles and their chunk caches
            self._episodes.popitem(last=False)
        return rows

    def block(self, path: str, index: int, number: int) -> dict[str, np.ndarray]:
        """Block `number` of episode `index` of `path`: each field's rows of steps number*rows .. (number+1)*rows - 1
        (a per-state field's rows after those steps), block -1 the reset row of the per-state fields."""
        key = (path, index, number)
        found = self._blocks.get(key)
        if found is not None:
            self._blocks.move_to_end(key)
            return found
        episode = self._rows_of(path, index)
        if number < 0:
            reset = episode.reset()
            found = {f.name: reset[f.name] for f in self.fields if f.per_state}
        else:
            start = number * self.rows
            block = episode.steps_of(self.names, start, min(episode.length, start + self.rows))
            found = {n: block[n] for n in self.names}
        self._keep(key, found)
        return found

    def _keep(self, key: tuple[str, int, int], arrays: dict[str, np.ndarray]) -> None:
        self._blocks[key] = arrays
        self._held += sum(a.nbytes for a in arrays.values())
        while self._held > self.max_bytes and len(self._blocks) > 1:
            _, dropped = self._blocks.popitem(last=False)
            self._held -= sum(a.nbytes for a in dropped.values())

    def field_rows(self, path: str, index: int, field: FieldSpec, rows: np.ndarray) -> np.ndarray:
        """Rows `rows` (in `field`'s own numbering) of `field` in episode `index` of `path`, as one array."""
        return self.gather([(path, index)], np.zeros(len(rows), dtype=np.int64), field, rows)

    def gather(self, episodes: Sequence[tuple[str, int]], which: np.ndarray, field: FieldSpec,
               rows: np.ndarray) -> np.ndarray:
        """Row `rows[k]` (in `field`'s own numbering) of `field` in episode `episodes[which[k]]` (a (path, index)),
        for every k, as one array: one fancy index per block the rows touch."""
        shifted = rows - 1 if field.per_state else rows  # a per-state row r > 0 is in the block of step r - 1
        numbers = np.where(shifted < 0, -1, shifted // self.rows)
        out = np.empty((len(rows), *field.shape), dtype=field.dtype)
        keys = which * (int(numbers.max(initial=0)) + 2) + numbers + 1  # one key per (episode, block)
        order = np.argsort(keys, kind="stable")
        bounds = np.flatnonzero(np.diff(keys[order])) + 1
        for at in np.split(order, bounds) if len(order) else ():
            number = int(numbers[at[0]])
            block = self.block(*episodes[int(which[at[0]])], number)[field.name]
            out[at] = block[0] if number < 0 else block[shifted[at] - number * self.rows]
        return out

    def close(self) -> None:
        """Close the readers this process opened (a cache used again opens them again)."""
        if os.getpid() == self._pid:
            for reader in self._readers.values():
                reader.close()
        self._no_handles()

    def __getstate__(self) -> dict[str, Any]:
        """What a DataLoader worker gets: the fields and sizes, none of the handles (each worker opens its own)."""
        return {"fields": self.fields, "names": self.names, "rows": self.rows, "max_bytes": self.max_bytes}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._no_handles()
