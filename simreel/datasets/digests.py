"""Digests of episodes as their rows pass: `FieldHashes` (each field's rows), `HashedRows` (an episode's rows
hashed as a reader passes through them), `episode_digest` and `field_digests`: what a copy, a merge or a conversion
checks what it wrote against."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from typing import Any

import numpy as np

from simreel.formats.base import EpisodeRows, PassedRows
from simreel.model.blocks import StepBlock
from simreel.model.meta import EpisodeMeta

__all__ = ["FieldHashes", "HashedRows", "episode_digest", "field_digests", "canonical_json"]


def canonical_json(value: Any) -> bytes:
    return json.dumps(value, sort_keys=True, separators=(",", ":")).encode()


class FieldHashes:
    """BLAKE2b-256 of each field's rows as blocks of them pass (`add`, in row order): the field's dtype and row
    shape, its row count and its bytes. Equal digests mean equal arrays (but for a collision of a 256-bit hash),
    however the rows were split in blocks: what a copy or a conversion hashes as it writes an episode, to check
    against the same hashes of what it reads back."""

    def __init__(self) -> None:
        self._hashes: dict[str, Any] = {}
        self._row_kinds: dict[str, str] = {}
        self._counts: dict[str, int] = {}

    def add(self, block: StepBlock, names: Iterable[str]) -> None:
        """Hash the rows of the fields `names` in `block`, after the rows hashed before them."""
        for name in names:
            a = np.ascontiguousarray(block[name])
            if name not in self._hashes:
                self._hashes[name], self._counts[name] = hashlib.blake2b(digest_size=32), 0
            kind = f"\0{a.dtype.str}\0{a.shape[1:]}\0"
            if self._row_kinds.get(name) != kind:  # once per field, unless a block changes its dtype or row shape
                self._row_kinds[name] = kind
                self._hashes[name].update(kind.encode())
            self._hashes[name].update(a.reshape(-1).view(np.uint8) if a.size else b"")
            self._counts[name] += len(a)

    def digests(self) -> dict[str, str]:
        """Field name -> the hex digest of its rows and row count, by name."""
        return {name: hashlib.blake2b(f"\0{name}\0{self._counts[name]}\0".encode() + h.digest(),
                                      digest_size=32).hexdigest()
                for name, h in sorted(self._hashes.items())}


class HashedRows(PassedRows):
    """An episode's rows (under new metadata, when given), hashed as a reader passes through them: the reset row
    first, then the steps in order, as `EpisodeWriter.write_rows` reads them. `digest()`, once every row has
    passed, is BLAKE2b-256 of the metadata and of every array's `FieldHashes` digest: equal digests mean equal
    episodes, however the rows were split in blocks."""

    def __init__(self, rows: EpisodeRows, meta: EpisodeMeta | None = None) -> None:
        super().__init__(rows, meta)
        self._fields = FieldHashes()
        self._next: int | None = None
        """The next step to hash; None before the reset row."""

    def passed_reset(self, block: StepBlock) -> StepBlock:
        if self._next is None:
            self._fields.add(block, [f.name for f in self.fields if f.per_state])
            self._next = 0
        return block

    def passed(self, start: int, block: StepBlock) -> StepBlock:
        if start != self._next:
            raise RuntimeError(f"episode {self.meta.index}: steps {start}.. read before step {self._next} was hashed")
        self._fields.add(block, [f.name for f in self.fields])
        self._next = start + block.rows
        return block

    def field_digests(self) -> dict[str, str]:
        """`FieldHashes.digests` of the episode's arrays, once every row has passed."""
        if self._next != self.length:
            raise RuntimeError(f"episode {self.meta.index}: digest taken at step {self._next} of {self.length}")
        return self._fields.digests()

    def digest(self) -> bytes:
        h = hashlib.blake2b(canonical_json(self.meta.to_json()), digest_size=32)
        for name, field_digest in self.field_digests().items():
            h.update(f"\0{name}\0{field_digest}".encode())
        return h.digest()


def episode_digest(rows: EpisodeRows) -> bytes:
    """`HashedRows.digest` of an episode, read a block at a time."""
    hashed = HashedRows(rows)
    hashed.read_through()
    return hashed.digest()


def field_digests(rows: EpisodeRows) -> dict[str, str]:
    """`HashedRows.field_digests` of an episode (its arrays, not its metadata), read a block at a time."""
    hashed = HashedRows(rows)
    hashed.read_through()
    return hashed.field_digests()
