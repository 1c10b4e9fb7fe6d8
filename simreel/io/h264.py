"""`H264Writer`: raw rgb24 frames, given a frame or a block of frames at a time, encoded into an H.264 (yuv420p) mp4 by
ffmpeg (imageio-ffmpeg's binary, the command imageio's writer runs), for `simreel video` and LeRobot exports.

ffmpeg is run here rather than through imageio's writer, which neither checks how ffmpeg ended nor keeps its
messages: a trailer ffmpeg could not write (a full disk) left a cut video reported as written, a frame it could not
take a broken pipe and ffmpeg's whole log. Its messages are kept and make the error (`encoder_error`): where the
storage refused, the one-line `storage_error` (exit 2)."""

from __future__ import annotations

import os
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from simreel.io.durable import STORAGE_ERRNOS, storage_error

__all__ = ["H264Writer", "encoder_error"]


class H264Writer:
    """One ffmpeg process writing the mp4 `path` from frames of `shape` (H, W, 3) at `fps` (`output_options`: more of
    ffmpeg's output options, e.g. ``("-crf", "18", "-g", "2")``); `label` names the video in errors (default `path`).
    `close` ends it and raises what stopped ffmpeg; `kill` drops it (the file is then not a video)."""

    def __init__(self, path: Path, shape: tuple[int, ...], fps: float, *, output_options: Sequence[str] = (),
                 label: Path | None = None) -> None:
        import imageio_ffmpeg

        height, width = shape[:2]
        self.path, self.label, self.frames = path, label or path, 0
        self._log = tempfile.TemporaryFile()
        command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-f", "rawvideo", "-vcodec", "rawvideo",
                   "-s", f"{width}x{height}", "-pix_fmt", "rgb24", "-r", str(fps), "-i", "-", "-an",
                   "-vcodec", "libx264", "-pix_fmt", "yuv420p", *output_options, "-v", "error", str(path)]
        self._process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log)
        self._broken = False

    def write(self, frames: np.ndarray) -> None:
        """Append one frame (H, W, 3) or a block of them (N, H, W, 3), uint8; where ffmpeg no longer takes them (it
        stopped: its log says why), the error `close` raises."""
        try:
            self._process.stdin.write(np.ascontiguousarray(frames, np.uint8).tobytes())
        except BrokenPipeError:
            self._broken = True
            self.close()
        self.frames += 1 if frames.ndim == 3 else len(frames)

    def close(self) -> str:
        """Finish the video and wait for ffmpeg; what it said (warnings of a video that was written), or the error
        for what stopped it (`encoder_error`)."""
        try:
            self._process.stdin.close()
        except BrokenPipeError:
            self._broken = True
        ended = self._process.wait() == 0 and not self._broken
        said = self._said()
        if not ended:
            raise encoder_error(self.label, said)
        return said

    def kill(self) -> None:
        """End ffmpeg at once (cleaning up after another error); nothing where it has ended."""
        if self._process.returncode is None:
            self._process.kill()
            self._process.wait()
        self._log.close()

    def _said(self) -> str:
        self._log.seek(0)
        said = self._log.read().decode(errors="replace").strip()
        self._log.close()
        return said


def encoder_error(path: Path, said: str) -> Exception:
    """The error for ffmpeg failing to write the video `path`, from what it `said`: where the storage refused (a
    full disk, a read-only file system) the one-line `storage_error` (exit 2), else a `RuntimeError` quoting ffmpeg's
    last line (not the user's doing)."""
    for code in sorted(STORAGE_ERRNOS):
        if os.strerror(code) in said:
            return storage_error(path, OSError(code, os.strerror(code)), lost="the video was not written")
    last = said.splitlines()[-1] if said else "no message"
    return RuntimeError(f"ffmpeg could not write {path}: {last}")
