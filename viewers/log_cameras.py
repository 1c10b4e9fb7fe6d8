"""Recorded camera observations (``sensor_data/<camera>/rgb|depth``) as images under ``cameras/<camera>/``."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import rerun as rr

from simreel.viewers.paths import CAMERAS

__all__ = ["camera_streams", "log_camera_formats", "log_camera_block"]

_DEPTH_METER = {"int16": 1000.0, "uint16": 1000.0}  # ManiSkill stores depth as int16 millimetres


def camera_streams(obs: Mapping[str, np.ndarray]) -> dict[str, str]:
    """`{entity path: obs key}` of the rgb and depth images in flat observations (T+1, H, W, C)."""
    out = {}
    for key, a in obs.items():
        parts = key.split("/")
        if len(parts) >= 3 and parts[-1] in ("rgb", "depth") and a.ndim == 4:
            out[f"{CAMERAS}/{parts[-2]}/{parts[-1]}"] = key
    return out


def log_camera_formats(rec: rr.RecordingStream, obs: Mapping[str, np.ndarray], streams: Mapping[str, str]) -> None:
    """The static image format of each stream (width, height, pixel type), so each step only sends bytes."""
    for path, key in streams.items():
        a = obs[key]
        _, h, w, c = a.shape
        if path.endswith("/rgb"):
            model = {1: "L", 3: "RGB", 4: "RGBA"}.get(c, "RGB")
            fmt = rr.components.ImageFormat(width=w, height=h, color_model=model, channel_datatype=_dtype(a))
            rec.log(path, rr.Image.from_fields(format=fmt), static=True)
        else:
            fmt = rr.components.ImageFormat(width=w, height=h, channel_datatype=_dtype(a))
            meter = _DEPTH_METER.get(a.dtype.name, 1.0)
            rec.log(path, rr.DepthImage.from_fields(format=fmt, meter=meter), static=True)


def _dtype(a: np.ndarray) -> str:
    return {"uint8": "U8", "int16": "I16", "uint16": "U16", "float32": "F32", "int32": "I32"}.get(a.dtype.name, "F32")


def log_camera_block(rec: rr.RecordingStream, obs: Mapping[str, np.ndarray], streams: Mapping[str, str], rows: slice,
                     indexes: list[rr.TimeColumn]) -> None:
    """State rows `rows` of every stream, one `send_columns` each."""
    for path, key in streams.items():
        a = obs[key]
        if a.dtype.name not in ("uint8", "int16", "uint16", "float32", "int32"):
            a = a.astype(np.float32)
        block = np.ascontiguousarray(a[rows])
        buffers = block.reshape(len(block), -1).view(np.uint8)
        cls = rr.Image if path.endswith("/rgb") else rr.DepthImage
        rec.send_columns(path, indexes=indexes, columns=cls.columns(buffer=buffers))
