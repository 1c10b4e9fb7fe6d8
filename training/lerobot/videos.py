"""Camera frames as LeRobot v3.0 videos: one mp4 a camera (``videos/<key>/chunk-XXX/file-YYY.mp4``) holding the
episodes one after another, H.264 (yuv420p) through the ffmpeg binary imageio-ffmpeg ships, at the dataset's fps, a
keyframe every `GOP` frames (LeRobot's default, for random access). Each episode's place in its file is the
episodes table's ``videos/<key>/chunk_index``, ``file_index``, ``from_timestamp`` and ``to_timestamp``; a new file
starts once one reaches `VIDEO_FILE_MB`. H.264 is lossy: a decoded frame differs from the recorded one by the codec's
error (`CRF` sets it), never bit for bit.

A camera is a recording's ``obs/sensor_data/<camera>/rgb`` field (uint8, (H, W, 3)); its video key is
``observation.images.<camera>``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simreel.io.h264 import H264Writer
from simreel.model.fields import FieldSpec
from simreel.training.lerobot.layout import VIDEO_PATH, chunk_file

__all__ = ["camera_fields", "video_key", "CameraVideos", "VideoFeature", "image_pixels", "as_image_stats", "CRF", "GOP", "VIDEO_FILE_MB"]

CRF = 18
"""x264's constant rate factor: 18 is visually lossless (LeRobot's default, 30, is coarser)."""
GOP = 2
"""Frames from one keyframe to the next (LeRobot's default)."""
VIDEO_FILE_MB = 200
"""A video file holds episodes until it reaches about this many MB (LeRobot's default)."""
_PIXEL_STRIDE = 4
"""Every 4th pixel of every 4th row makes an episode's image statistics."""


def camera_fields(fields: Sequence[FieldSpec]) -> list[FieldSpec]:
    """The RGB camera fields among `fields`: ``obs/sensor_data/<camera>/rgb``, uint8 (H, W, 3)."""
    return [f for f in fields if f.name.startswith("obs/sensor_data/") and f.name.endswith("/rgb")
            and f.dtype == "uint8" and len(f.shape) == 3 and f.shape[2] == 3]


def video_key(field: FieldSpec) -> str:
    """``observation.images.<camera>`` of ``obs/sensor_data/<camera>/rgb``."""
    return "observation.images." + field.name.split("/")[2]


class VideoFeature:
    """A video feature of info.json: its key, its frames' (H, W, 3) and the encoding, as LeRobot writes them."""

    def __init__(self, key: str, shape: tuple[int, ...], fps: float) -> None:
        self.key, self.shape, self.fps = key, tuple(int(n) for n in shape), fps

    def info(self) -> dict[str, Any]:
        height, width, channels = self.shape
        return {"dtype": "video", "shape": [height, width, channels], "names": ["height", "width", "channels"],
                "info": {"video.height": height, "video.width": width, "video.codec": "h264",
                         "video.pix_fmt": "yuv420p", "video.is_depth_map": False,
                         "video.fps": int(self.fps) if float(self.fps).is_integer() else self.fps,
                         "video.channels": channels, "has_audio": False}}


def image_pixels(frames: np.ndarray) -> np.ndarray:
    """The pixels an episode's image statistics are taken over: a strided sample of `frames` (T, H, W, 3) as rows
    (n, 3) scaled to [0, 1], as LeRobot takes image statistics per channel."""
    return frames[:, ::_PIXEL_STRIDE, ::_PIXEL_STRIDE].reshape(-1, frames.shape[-1]) / 255.0


def as_image_stats(stats: dict[str, Any]) -> dict[str, Any]:
    """Per-channel statistics (each (3,)) in the shape LeRobot keeps them for an image feature, (3, 1, 1)."""
    return {k: v if k == "count" else np.asarray(v).reshape(-1, 1, 1).tolist() for k, v in stats.items()}


class CameraVideos:
    """The video files of each camera, episodes appended in order (`episode`), closed by `finish` (or `abort`)."""

    def __init__(self, folder: Path, features: Sequence[VideoFeature], fps: float) -> None:
        self.folder, self.features, self.fps = folder, list(features), fps
        self._encoders: dict[str, H264Writer] = {}
        self._file_numbers = {f.key: -1 for f in self.features}

    def _encoder(self, feature: VideoFeature) -> H264Writer:
        current = self._encoders.get(feature.key)
        if current is None or _bytes_written(current.path) >= VIDEO_FILE_MB * 2**20:
            if current is not None:
                current.close()
            self._file_numbers[feature.key] += 1
            where = chunk_file(self._file_numbers[feature.key])
            path = self.folder / VIDEO_PATH.format(video_key=feature.key, **where)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._encoders[feature.key] = current = H264Writer(path, feature.shape, self.fps,
                                                               output_options=("-crf", str(CRF), "-g", str(GOP)))
        return current

    def episode(self, frames: dict[str, np.ndarray]) -> dict[str, Any]:
        """Append one episode's frames (video key -> (T, H, W, 3) uint8) to each camera's file; its columns of the
        episodes table."""
        columns = {}
        for feature in self.features:
            encoder = self._encoder(feature)
            where = chunk_file(self._file_numbers[feature.key])
            start = encoder.frames / self.fps
            encoder.write(frames[feature.key])
            columns.update({f"videos/{feature.key}/chunk_index": where["chunk_index"],
                            f"videos/{feature.key}/file_index": where["file_index"],
                            f"videos/{feature.key}/from_timestamp": start,
                            f"videos/{feature.key}/to_timestamp": encoder.frames / self.fps})
        return columns

    def finish(self) -> dict[str, int]:
        """Close every video; the number of files each camera's video key has."""
        for encoder in self._encoders.values():
            encoder.close()
        self._encoders.clear()
        return {key: number + 1 for key, number in self._file_numbers.items()}

    def abort(self) -> None:
        for encoder in self._encoders.values():
            encoder.kill()
        self._encoders.clear()


def _bytes_written(path: Path) -> int:
    return path.stat().st_size if path.exists() else 0
