"""The exact bytes of simreel's MCAP data channels: which arrays a block holds and how they are laid out.

Two channels carry the data bit-exactly (no float formatting):

- `/simreel/reset`: one message per episode, row 0 of the per-state fields (state/obs/poses after reset);
- `/simreel/steps`: one message per block of consecutive steps, every field.

A message is a 12-byte little-endian header `(episode index, first row, rows)` followed by each field's
rows in C order, fields in the order of the channel's field table. The field table (name, numpy dtype
string with byte order, per-row shape) is the channel's schema (encoding `simreel-fields`), derived from
the recording's `simreel.model.fields.episode_fields`. Nothing else in simreel knows these bytes.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.model.fields import FieldSpec, episode_fields
from simreel.model.json_input import json_value
from simreel.model.meta import RecordingMeta

__all__ = [
    "WireField",
    "step_fields",
    "reset_fields",
    "fields_to_schema",
    "fields_from_schema",
    "pack_block",
    "unpack_header",
    "unpack_block",
    "SCHEMA_ENCODING",
    "MESSAGE_ENCODING",
    "HEADER",
]

SCHEMA_ENCODING = "simreel-fields"
MESSAGE_ENCODING = "simreel-raw"
HEADER = struct.Struct("<III")
"""episode index, first row (the step index of the block's first step), rows in the block."""


@dataclass(frozen=True)
class WireField:
    """One array of a message: a `FieldSpec` with its little-endian dtype string (`<f4`, `|b1`)."""

    name: str
    dtype: str
    shape: tuple[int, ...]

    @classmethod
    def of(cls, spec: FieldSpec) -> WireField:
        return cls(spec.name, np.dtype(spec.dtype).newbyteorder("<").str, tuple(int(s) for s in spec.shape))

    @property
    def row_bytes(self) -> int:
        return int(np.dtype(self.dtype).itemsize * int(np.prod(self.shape, dtype=np.int64)))


def reset_fields(meta: RecordingMeta) -> list[WireField]:
    """The field table of `/simreel/reset` messages: the per-state fields."""
    return [WireField.of(f) for f in episode_fields(meta) if f.per_state]


def step_fields(meta: RecordingMeta) -> list[WireField]:
    """The field table of `/simreel/steps` messages: every field (per-state ones: rows 1..T)."""
    return [WireField.of(f) for f in episode_fields(meta)]


def fields_to_schema(fields: list[WireField]) -> bytes:
    doc = {
        "header": "little-endian uint32 episode, uint32 first_row, uint32 rows",
        "fields": [{"name": f.name, "dtype": f.dtype, "shape": list(f.shape)} for f in fields],
    }
    return json.dumps(doc).encode()


def fields_from_schema(data: bytes) -> list[WireField]:
    doc = json_value(data, "the step schema")
    return [WireField(str(f["name"]), str(f["dtype"]), tuple(int(s) for s in f["shape"])) for f in doc["fields"]]


def pack_block(fields: list[WireField], arrays: dict[str, Any], *, episode: int, first_row: int, rows: int) -> bytes:
    """Header + every field's `rows` rows in its wire dtype; `arrays` are already checked against the field
    table (`simreel.model.blocks.StepBlock.conform`)."""
    parts = [HEADER.pack(episode, first_row, rows)]
    parts += [np.ascontiguousarray(arrays[f.name], dtype=f.dtype).tobytes() for f in fields]
    return b"".join(parts)


def unpack_header(data: bytes) -> tuple[int, int, int]:
    """(episode index, first row, rows) of a block message."""
    return HEADER.unpack_from(data)


def unpack_block(fields: list[WireField], data: bytes) -> tuple[int, int, dict[str, np.ndarray]]:
    """(first row, rows, {field name: (rows, *shape) array}); raises ValueError if the sizes disagree."""
    _, first_row, rows = HEADER.unpack_from(data)
    expected = HEADER.size + rows * sum(f.row_bytes for f in fields)
    if len(data) != expected:
        raise ValueError(f"a block of {rows} rows has {len(data)} bytes, expected {expected}")
    out: dict[str, np.ndarray] = {}
    offset = HEADER.size
    for f in fields:
        n = rows * f.row_bytes
        out[f.name] = np.frombuffer(data, f.dtype, rows * int(np.prod(f.shape, dtype=np.int64)), offset).reshape(
            rows, *f.shape
        )
        offset += n
    return first_row, rows, out
