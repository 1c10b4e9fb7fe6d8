"""The exact bytes of simreel's MCAP data channels: which arrays a block holds and how they are laid out.

Two channels carry the data bit-exactly (no float formatting):

- `/simreel/reset`: one message per episode, row 0 of the T+1-row fields (state/obs/poses after reset);
- `/simreel/steps`: one message per block of consecutive steps, every per-step field.

A message is a 12-byte little-endian header `(episode index, first row, rows)` followed by each field's
rows in C order, fields in the order of the channel's field table. The field table (name, numpy dtype
string with byte order, per-row shape) is the channel's schema (encoding `simreel-fields`), derived once
from `RecordingMeta` by `step_fields`/`reset_fields`. Nothing else in simreel knows these bytes.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.episode import FLAG_FIELDS, RecordingMeta
from simreel.errors import EpisodeLayoutError

__all__ = [
    "Field",
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
class Field:
    """One array of a block: `name` is an `Episode` attribute or `<group>/<key path>`."""

    name: str
    dtype: str
    """numpy dtype string with byte order, e.g. `<f4`, `|b1`."""
    shape: tuple[int, ...]
    """Shape of one row."""

    @property
    def row_bytes(self) -> int:
        return int(np.dtype(self.dtype).itemsize * int(np.prod(self.shape, dtype=np.int64)))


def _field(name: str, dtype: Any, shape: Any) -> Field:
    return Field(name, np.dtype(dtype).newbyteorder("<").str, tuple(int(s) for s in shape))


def _row_fields(meta: RecordingMeta) -> list[Field]:
    """Fields with T+1 rows per episode (row 0: after reset)."""
    out = [_field(f"env_states/{p}", s.dtype, s.shape) for p, s in meta.state_layout.items()]
    out += [_field(f"obs/{p}", s.dtype, s.shape) for p, s in meta.obs_layout.items()]
    if meta.pose_bodies:
        out.append(_field("body_poses", np.float32, (len(meta.pose_bodies), 7)))
    return out


def reset_fields(meta: RecordingMeta) -> list[Field]:
    """The field table of `/simreel/reset` messages."""
    return _row_fields(meta)


def step_fields(meta: RecordingMeta) -> list[Field]:
    """The field table of `/simreel/steps` messages (the same dtypes the HDF5 writer stores)."""
    out = [
        _field("actions", np.float32, meta.action_space.get("shape", [0])),
        _field("rewards", np.float32, ()),
        *(_field(name, bool, ()) for name in FLAG_FIELDS),
        *(_field(f"info/{k}", s.dtype, s.shape) for k, s in meta.info_layout.items()),
    ]
    if meta.contact_channels:
        out.append(_field("contact_forces", np.float32, (len(meta.contact_channels), 3)))
    # State, obs and poses after each step: the T+1-row fields, rows 1..T.
    return out + _row_fields(meta)


def fields_to_schema(fields: list[Field]) -> bytes:
    doc = {
        "header": "little-endian uint32 episode, uint32 first_row, uint32 rows",
        "fields": [{"name": f.name, "dtype": f.dtype, "shape": list(f.shape)} for f in fields],
    }
    return json.dumps(doc).encode()


def fields_from_schema(data: bytes) -> list[Field]:
    doc = json.loads(data)
    return [Field(str(f["name"]), str(f["dtype"]), tuple(int(s) for s in f["shape"])) for f in doc["fields"]]


def _lookup(source: Any, name: str) -> Any:
    """`source.<name>` or `source.<group>[<key path>]` (source: a StepBlock or a dict of row-0 arrays)."""
    if isinstance(source, dict):
        return source.get(name)
    head, _, rest = name.partition("/")
    if rest:
        return getattr(source, head).get(rest)
    return getattr(source, name)


def pack_block(fields: list[Field], source: Any, *, episode: int, first_row: int, rows: int) -> bytes:
    """Header + every field's `rows` rows, cast to the field's dtype; `EpisodeLayoutError` (naming the
    episode, the field and the shapes) when one is missing or has the wrong row shape."""
    parts = [HEADER.pack(episode, first_row, rows)]
    for f in fields:
        a = _lookup(source, f.name)
        if a is None:
            raise EpisodeLayoutError(f"episode {episode}: no {f.name} to write (the recording's layout lists it)")
        a = np.asarray(a)
        if a.shape != (rows, *f.shape):
            raise EpisodeLayoutError(
                f"episode {episode}: {f.name} has shape {a.shape}, expected {(rows, *f.shape)} from the layout"
            )
        parts.append(np.ascontiguousarray(a, dtype=f.dtype).tobytes())
    return b"".join(parts)


def unpack_header(data: bytes) -> tuple[int, int, int]:
    """(episode index, first row, rows) of a block message."""
    return HEADER.unpack_from(data)


def unpack_block(fields: list[Field], data: bytes) -> tuple[int, int, dict[str, np.ndarray]]:
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
