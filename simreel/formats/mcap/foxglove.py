"""Foxglove's well-known protobuf messages, encoded without a protobuf runtime.

Only what simreel's viewable MCAP channels need: `foxglove.FrameTransforms` (world poses of bodies,
shown by Foxglove's 3D panel and decoded by Rerun's MCAP loader) and `foxglove.Log` (episode events).
The schemas are Foxglove's own `FileDescriptorSet`s (from `foxglove-schemas-protobuf` 0.4.0,
regenerated and compared in `tests/formats/test_mcap.py`), so viewers find them under the exact names
they recognise. Messages are written with the protobuf wire format by hand: a block of steps becomes
one numpy byte template filled in place, far cheaper than building protobuf objects per step.
"""

from __future__ import annotations

import base64
from collections.abc import Sequence

import numpy as np

from simreel.formats.mcap.wire import len_field, timestamp, varint

__all__ = [
    "FRAME_TRANSFORMS_SCHEMA",
    "LOG_SCHEMA",
    "LOG_INFO",
    "LOG_WARNING",
    "FrameTransformsEncoder",
    "encode_log",
]

# FileDescriptorSet of foxglove.FrameTransforms and foxglove.Log (with their dependencies), base64.
_FRAME_TRANSFORMS_FDS = (
    "CmcKGWZveGdsb3ZlL1F1YXRlcm5pb24ucHJvdG8SCGZveGdsb3ZlIjgKClF1YXRlcm5pb24SCQoBeBgBIAEoARIJCgF5GAIg"
    "ASgBEgkKAXoYAyABKAESCQoBdxgEIAEoAWIGcHJvdG8zClYKFmZveGdsb3ZlL1ZlY3RvcjMucHJvdG8SCGZveGdsb3ZlIioK"
    "B1ZlY3RvcjMSCQoBeBgBIAEoARIJCgF5GAIgASgBEgkKAXoYAyABKAFiBnByb3RvMwr/AQofZ29vZ2xlL3Byb3RvYnVmL3Rp"
    "bWVzdGFtcC5wcm90bxIPZ29vZ2xlLnByb3RvYnVmIjsKCVRpbWVzdGFtcBIYCgdzZWNvbmRzGAEgASgDUgdzZWNvbmRzEhQK"
    "BW5hbm9zGAIgASgFUgVuYW5vc0KFAQoTY29tLmdvb2dsZS5wcm90b2J1ZkIOVGltZXN0YW1wUHJvdG9QAVoyZ29vZ2xlLmdv"
    "bGFuZy5vcmcvcHJvdG9idWYvdHlwZXMva25vd24vdGltZXN0YW1wcGL4AQGiAgNHUEKqAh5Hb29nbGUuUHJvdG9idWYuV2Vs"
    "bEtub3duVHlwZXNiBnByb3RvMwrIAgodZm94Z2xvdmUvRnJhbWVUcmFuc2Zvcm0ucHJvdG8SCGZveGdsb3ZlGhlmb3hnbG92"
    "ZS9RdWF0ZXJuaW9uLnByb3RvGhZmb3hnbG92ZS9WZWN0b3IzLnByb3RvGh9nb29nbGUvcHJvdG9idWYvdGltZXN0YW1wLnBy"
    "b3RvIsABCg5GcmFtZVRyYW5zZm9ybRItCgl0aW1lc3RhbXAYASABKAsyGi5nb29nbGUucHJvdG9idWYuVGltZXN0YW1wEhcK"
    "D3BhcmVudF9mcmFtZV9pZBgCIAEoCRIWCg5jaGlsZF9mcmFtZV9pZBgDIAEoCRImCgt0cmFuc2xhdGlvbhgEIAEoCzIRLmZv"
    "eGdsb3ZlLlZlY3RvcjMSJgoIcm90YXRpb24YBSABKAsyFC5mb3hnbG92ZS5RdWF0ZXJuaW9uYgZwcm90bzMKkgEKHmZveGds"
    "b3ZlL0ZyYW1lVHJhbnNmb3Jtcy5wcm90bxIIZm94Z2xvdmUaHWZveGdsb3ZlL0ZyYW1lVHJhbnNmb3JtLnByb3RvIj8KD0Zy"
    "YW1lVHJhbnNmb3JtcxIsCgp0cmFuc2Zvcm1zGAEgAygLMhguZm94Z2xvdmUuRnJhbWVUcmFuc2Zvcm1iBnByb3RvMw=="
)
_LOG_FDS = (
    "Cv8BCh9nb29nbGUvcHJvdG9idWYvdGltZXN0YW1wLnByb3RvEg9nb29nbGUucHJvdG9idWYiOwoJVGltZXN0YW1wEhgKB3Nl"
    "Y29uZHMYASABKANSB3NlY29uZHMSFAoFbmFub3MYAiABKAVSBW5hbm9zQoUBChNjb20uZ29vZ2xlLnByb3RvYnVmQg5UaW1l"
    "c3RhbXBQcm90b1ABWjJnb29nbGUuZ29sYW5nLm9yZy9wcm90b2J1Zi90eXBlcy9rbm93bi90aW1lc3RhbXBwYvgBAaICA0dQ"
    "QqoCHkdvb2dsZS5Qcm90b2J1Zi5XZWxsS25vd25UeXBlc2IGcHJvdG8zCqsCChJmb3hnbG92ZS9Mb2cucHJvdG8SCGZveGds"
    "b3ZlGh9nb29nbGUvcHJvdG9idWYvdGltZXN0YW1wLnByb3RvIuEBCgNMb2cSLQoJdGltZXN0YW1wGAEgASgLMhouZ29vZ2xl"
    "LnByb3RvYnVmLlRpbWVzdGFtcBIiCgVsZXZlbBgCIAEoDjITLmZveGdsb3ZlLkxvZy5MZXZlbBIPCgdtZXNzYWdlGAMgASgJ"
    "EgwKBG5hbWUYBCABKAkSDAoEZmlsZRgFIAEoCRIMCgRsaW5lGAYgASgHIkwKBUxldmVsEgsKB1VOS05PV04QABIJCgVERUJV"
    "RxABEggKBElORk8QAhILCgdXQVJOSU5HEAMSCQoFRVJST1IQBBIJCgVGQVRBTBAFYgZwcm90bzM="
)

FRAME_TRANSFORMS_SCHEMA = ("foxglove.FrameTransforms", base64.b64decode("".join(_FRAME_TRANSFORMS_FDS)))
"""(schema name, FileDescriptorSet bytes) for an MCAP schema record with encoding "protobuf"."""
LOG_SCHEMA = ("foxglove.Log", base64.b64decode("".join(_LOG_FDS)))

LOG_INFO = 2
LOG_WARNING = 3


# FrameTransform fields 4 (translation: Vector3 {x=1 y=2 z=3}) and 5 (rotation: Quaternion {x=1 y=2 z=3
# w=4}); every double is a one-byte tag + 8 bytes, so this part has a fixed size and fixed offsets.
_POSE = (
    b"\x22\x1b" + b"\x09" + bytes(8) + b"\x11" + bytes(8) + b"\x19" + bytes(8)
    + b"\x2a\x24" + b"\x09" + bytes(8) + b"\x11" + bytes(8) + b"\x19" + bytes(8) + b"\x21" + bytes(8)
)
_POSE_DTYPE = np.dtype({
    "names": ["x", "y", "z", "qx", "qy", "qz", "qw"],
    "formats": ["<f8"] * 7,
    "offsets": [3, 12, 21, 32, 41, 50, 59],
    "itemsize": len(_POSE),
})
_XYZ_XYZW = [0, 1, 2, 4, 5, 6, 3]
"""Where each `_POSE_DTYPE` field comes from in SAPIEN's `[x y z qw qx qy qz]`."""


class FrameTransformsEncoder:
    """Encodes poses of fixed frames as `foxglove.FrameTransforms` messages, one per step.

    Args:
        parents: parent frame id of each transform.
        children: child frame id of each transform (same length as `parents`).
    """

    def __init__(self, parents: Sequence[str], children: Sequence[str]) -> None:
        if len(parents) != len(children):
            raise ValueError(f"{len(parents)} parent frames for {len(children)} child frames")
        self._names = [
            len_field(0x12, p.encode()) + len_field(0x1A, c.encode()) for p, c in zip(parents, children, strict=True)
        ]
        self._templates: dict[int, tuple[np.ndarray, np.dtype]] = {}

    def __len__(self) -> int:
        return len(self._names)

    def _template(self, ts_len: int) -> tuple[np.ndarray, np.dtype]:
        """Message bytes for a timestamp of `ts_len` bytes, and a packed record dtype whose fields
        `t{b}` (the timestamp) and `p{b}` (translation + rotation) of body b sit where the template has them."""
        cached = self._templates.get(ts_len)
        if cached is not None:
            return cached
        buf = bytearray()
        names: list[str] = []
        formats: list[str] = []
        offsets: list[int] = []
        for b, frame_names in enumerate(self._names):
            ts_field = b"\x0a" + varint(ts_len)
            body = ts_field + bytes(ts_len) + frame_names + _POSE
            buf += b"\x0a" + varint(len(body))
            start = len(buf)
            if ts_len:
                names.append(f"t{b}")
                formats.append(f"V{ts_len}")
                offsets.append(start + len(ts_field))
            names.append(f"p{b}")
            formats.append(f"V{len(_POSE)}")
            offsets.append(start + len(body) - len(_POSE))
            buf += body
        dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": len(buf)})
        cached = (np.frombuffer(bytes(buf), np.uint8), dtype)
        self._templates[ts_len] = cached
        return cached

    def encode(self, poses: np.ndarray, times_ns: Sequence[int]) -> list[bytes]:
        """One message per row of `poses` (k, B, 7) `[x y z qw qx qy qz]` (SAPIEN order) at `times_ns`.

        Foxglove and Rerun take quaternions as xyzw; the reordering happens here.
        """
        k, nb = poses.shape[:2]
        if nb != len(self._names):
            raise ValueError(f"poses hold {nb} bodies, the encoder was made for {len(self._names)}")
        pose_fields = np.empty((k, nb, len(_POSE)), np.uint8)
        pose_fields[:] = np.frombuffer(_POSE, np.uint8)
        doubles = pose_fields.view(_POSE_DTYPE)[..., 0]
        for j, name in enumerate(_POSE_DTYPE.names):
            doubles[name] = poses[..., _XYZ_XYZW[j]]
        pose_bytes = pose_fields.view(f"V{len(_POSE)}")[..., 0]
        stamps = [timestamp(t) for t in times_ns]
        stamp_lens = np.fromiter(map(len, stamps), np.intp, k)
        out: list[bytes] = [b""] * k
        for ts_len in np.unique(stamp_lens).tolist():
            rows = np.flatnonzero(stamp_lens == ts_len).tolist()
            template, dtype = self._template(ts_len)
            msgs = np.empty(len(rows), dtype)
            msgs.view(np.uint8).reshape(len(rows), -1)[:] = template
            group = pose_bytes[rows]
            ts = np.array([stamps[i] for i in rows], f"V{ts_len}") if ts_len else None
            for b in range(nb):
                if ts is not None:
                    msgs[f"t{b}"] = ts
                msgs[f"p{b}"] = group[:, b]
            raw = msgs.tobytes()
            size = dtype.itemsize
            for n, i in enumerate(rows):
                out[i] = raw[n * size:(n + 1) * size]
        return out


def encode_log(time_ns: int, level: int, message: str, name: str) -> bytes:
    """A `foxglove.Log` message."""
    return (
        len_field(0x0A, timestamp(time_ns))
        + b"\x10" + varint(level)
        + len_field(0x1A, message.encode())
        + len_field(0x22, name.encode())
    )


