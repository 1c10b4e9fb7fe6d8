"""Frames of an exported H.264 video, decoded by the ffmpeg imageio-ffmpeg ships, and the check that they are the
recorded ones within the codec's error (x264, crf 18, yuv420p: a mean absolute error of 3.6-3.9 of 255 a frame
measured on PickCube's 128x128 camera, single pixels up to ~130 at coloured edges)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import imageio_ffmpeg
import numpy as np

__all__ = ["CODEC_MEAN_ERROR", "decoded_frames", "check_within_codec_error"]

CODEC_MEAN_ERROR = 6.0
"""The largest mean absolute error (of 255) a decoded frame may have."""


def decoded_frames(video: Path, shape: tuple[int, ...]) -> np.ndarray:
    """Every frame of `video`, (N, *shape) uint8."""
    raw = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(video), "-f", "rawvideo",
                          "-pix_fmt", "rgb24", "-"], capture_output=True, check=True, timeout=120).stdout
    return np.frombuffer(raw, np.uint8).reshape(-1, *shape)


def check_within_codec_error(decoded: np.ndarray, recorded: np.ndarray) -> None:
    """Each decoded frame within `CODEC_MEAN_ERROR` of its recorded frame and nearer it than any other: no frame
    shifted or repeated."""
    assert decoded.shape == recorded.shape
    errors = np.abs(decoded.astype(np.int16)[:, None] - recorded.astype(np.int16)[None]).mean(axis=(2, 3, 4))
    assert (np.diag(errors) <= CODEC_MEAN_ERROR).all(), np.diag(errors)
    assert (errors.argmin(axis=1) == np.arange(len(recorded))).all(), errors.argmin(axis=1)
