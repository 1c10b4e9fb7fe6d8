"""Recorded camera observations (``sensor_data/<camera>/rgb|depth``) as images under ``cameras/<camera>/``.

The streams and their formats come from the recording's field table (no frame is read for them); the frames are
logged a block of rows at a time, as the session reads them (`log_camera_block`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import rerun as rr

from simreel.model.fields import FieldSpec
from simreel.viewers.paths import CAMERAS

__all__ = ["camera_streams", "log_camera_formats", "log_camera_block"]

_DEPTH_METER = {"int16": 1000.0, "uint16": 1000.0}  # ManiSkill stores depth as int16 millimetres


def camera_streams(fields: Sequence[FieldSpec]) -> dict[str, FieldSpec]:
    """`{entity path: field}` of the rgb and depth images among an episode's fields (rows of (H, W, C))."""
    out = {}
    for f in fields:
        parts = f.name.split("/")
        if parts[0] == "obs" and len(parts) >= 4 and parts[-1] in ("rgb", "depth") and len(f.shape) == 3:
            out[f"{CAMERAS}/{parts[-2]}/{parts[-1]}"] = f
    return out


def log_camera_formats(rec: rr.RecordingStream, streams: Mapping[str, FieldSpec]) -> None:
    """The static image format of each stream (width, height, pixel type), so each step only sends bytes."""
    for path, f in streams.items():
        h, w, c = f.shape
        dtype = np.dtype(f.dtype)
        if path.endswith("/rgb"):
            model = {1: "L", 3: "RGB", 4: "RGBA"}.get(c, "RGB")
            fmt = rr.components.ImageFormat(width=w, height=h, color_model=model, channel_datatype=_dtype(dtype))
            rec.log(path, rr.Image.from_fields(format=fmt), static=True)
        else:
            fmt = rr.components.ImageFormat(width=w, height=h, channel_datatype=_dtype(dtype))
            meter = _DEPTH_METER.get(dtype.name, 1.0)
            rec.log(path, rr.DepthImage.from_fields(format=fmt, meter=meter), static=True)


def _dtype(dtype: np.dtype) -> str:
    return {"uint8": "U8", "int16": "I16", "uint16": "U16", "float32": "F32", "int32": "I32"}.get(dtype.name, "F32")


def log_camera_block(rec: rr.RecordingStream, arrays: Mapping[str, np.ndarray], streams: Mapping[str, FieldSpec],
                     indexes: list[rr.TimeColumn]) -> None:
    """A block of rows of every stream (`arrays`: field name -> rows, at the time points of `indexes`), one
    `send_columns` each."""
    for path, f in streams.items():
        a = arrays[f.name]
        if a.dtype.name not in ("uint8", "int16", "uint16", "float32", "int32"):
            a = a.astype(np.float32)
        block = np.ascontiguousarray(a)
        buffers = block.reshape(len(block), -1).view(np.uint8)
        cls = rr.Image if path.endswith("/rgb") else rr.DepthImage
        rec.send_columns(path, indexes=indexes, columns=cls.columns(buffer=buffers))
