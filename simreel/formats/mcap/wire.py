"""The protobuf wire format, by hand, for the few Foxglove messages simreel writes (`foxglove`, `scene`): varints,
length-delimited fields, doubles, timestamps. No protobuf runtime: messages are bytes put together here."""

from __future__ import annotations

import functools
import struct

__all__ = ["varint", "len_field", "varint_field", "double_field", "timestamp"]

_DOUBLE = struct.Struct("<d")


def varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def len_field(tag: int, payload: bytes) -> bytes:
    """A length-delimited field (a string, bytes, a sub-message or a packed array) with its one-byte `tag`."""
    return bytes([tag]) + varint(len(payload)) + payload


@functools.lru_cache(maxsize=1 << 14)
def varint_field(tag: int, n: int) -> bytes:
    """A varint field, or nothing for 0 (protobuf omits defaults); cached: step times repeat their parts."""
    return bytes([tag]) + varint(n) if n else b""


def double_field(tag: int, x: float) -> bytes:
    """A double field (wire type 1), written even when 0."""
    return bytes([tag]) + _DOUBLE.pack(x)


def timestamp(ns: int) -> bytes:
    """google.protobuf.Timestamp {seconds=1, nanos=2} of `ns` nanoseconds."""
    sec, nanos = divmod(int(ns), 1_000_000_000)
    return varint_field(0x08, sec) + varint_field(0x10, nanos)
