"""One shard of an export: a run of consecutive episodes written by one process (`write_shard`) into its own data
and video files, streamed an episode at a time as one process writes a whole export: each episode's frames appended
to the current data file as one row group (a new file once it reaches ~100 MB), its camera frames to each camera's
video. What the final step needs comes back (`ShardResult`): the episodes' rows of the episodes table (their files
numbered from 0 within the shard), their statistics' moments, and how many files of each kind the shard wrote.

Every episode's place in the dataset is planned before any shard starts (`PlannedEpisode`: the episodes' lengths
are known up front), so a shard's frames carry their final ``episode_index`` and ``index``."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from simreel.formats import open_reader
from simreel.training.episodes import EpisodeRef
from simreel.training.lerobot.frame_stats import episode_moments, episode_stats
from simreel.training.lerobot.frames import FrameLayout
from simreel.training.lerobot.layout import DATA_FILE_MB, DATA_PATH, FrameFeature, arrow_column, chunk_file
from simreel.training.lerobot.videos import CameraVideos, VideoFeature, as_image_stats, image_pixels

__all__ = ["PlannedEpisode", "ExportJob", "ShardResult", "write_shard"]


@dataclass(frozen=True)
class PlannedEpisode:
    """An episode of the export and its place in the dataset: its ``episode_index``, the ``index`` of its first
    frame, its task and ``task_index``."""

    ref: EpisodeRef
    episode_index: int
    first_index: int
    task: str
    task_index: int


@dataclass(frozen=True)
class ExportJob:
    """What every shard writes with (sent to each worker process): each source file's frame layout, the data files'
    features, the cameras' video features and the fps."""

    layouts: dict[str, FrameLayout]
    features: list[FrameFeature]
    videos: list[VideoFeature]
    fps: float


@dataclass
class ShardResult:
    """What a shard wrote: its episodes' rows of the episodes table (data and video file numbers counted from 0 in
    the shard), each episode's `episode_moments`, and the number of data files and of each camera's video files."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    moments: list[dict[str, Any]] = field(default_factory=list)
    data_files: int = 0
    video_files: dict[str, int] = field(default_factory=dict)


def write_shard(job: ExportJob, episodes: Sequence[PlannedEpisode], folder: Path,
                progress: Callable[[int], Any] | None = None) -> ShardResult:
    """Write `episodes` (consecutive in the dataset) into `folder` in the dataset's layout, calling `progress` with
    each episode's frame count once it is written. Where anything stops it, its ffmpeg processes are ended."""
    writer = _ShardWriter(folder, job.features, CameraVideos(folder, job.videos, job.fps))
    try:
        for planned in episodes:
            with open_reader(planned.ref.path) as reader:
                frames = job.layouts[planned.ref.path].frames(
                    reader.open_episode(planned.ref.index), fps=job.fps, episode_index=planned.episode_index,
                    first_index=planned.first_index, task_index=planned.task_index)
            writer.episode(planned, frames)
            if progress is not None:
                progress(planned.ref.length)
    except BaseException:
        writer.abort()  # no ffmpeg left running
        raise
    return writer.close()


class _ShardWriter:
    """The data files of a shard (one row group an episode, a new file past ~100 MB), its videos and its rows."""

    def __init__(self, folder: Path, features: Sequence[FrameFeature], videos: CameraVideos) -> None:
        self.folder, self.features, self.videos = folder, list(features), videos
        self.schema = pa.schema([pa.field(f.key, f.arrow_type(), nullable=False) for f in self.features])
        self._file_number = -1
        self._file: pq.ParquetWriter | None = None
        self._file_bytes = 0
        self.result = ShardResult()

    def _data_file(self, incoming: int) -> dict[str, int]:
        if self._file is None or self._file_bytes + incoming > DATA_FILE_MB * 2**20:
            if self._file is not None:
                self._file.close()
            self._file_number += 1
            path = self.folder / DATA_PATH.format(**chunk_file(self._file_number))
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file, self._file_bytes = pq.ParquetWriter(path, self.schema), 0
        return chunk_file(self._file_number)

    def episode(self, planned: PlannedEpisode, frames: dict[str, np.ndarray]) -> None:
        images = {f.key: frames.pop(f.key) for f in self.videos.features}
        length = len(frames["index"])
        if length != planned.ref.length:
            raise RuntimeError(f"{planned.ref.path}: episode {planned.ref.index} has {length} frames, not the "
                               f"{planned.ref.length} its recording's metadata says")
        table = pa.table([arrow_column(f, frames[f.key]) for f in self.features], schema=self.schema)
        where = self._data_file(table.nbytes)
        self._file.write_table(table)
        self._file_bytes += table.nbytes
        stats = {key: episode_stats(values) for key, values in frames.items()}
        pixels = {key: image_pixels(values) for key, values in images.items()}
        pixel_stats = {key: episode_stats(values) for key, values in pixels.items()}
        self.result.moments.append({**episode_moments(frames, stats), **episode_moments(pixels, pixel_stats)})
        row = {"episode_index": planned.episode_index, "tasks": [planned.task], "length": length,
               "data/chunk_index": where["chunk_index"], "data/file_index": where["file_index"],
               "dataset_from_index": planned.first_index, "dataset_to_index": planned.first_index + length,
               "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
               "simreel/source_file": planned.ref.path, "simreel/source_episode": planned.ref.index,
               "simreel/verdict": planned.ref.verdict, **self.videos.episode(images)}
        for key, s in stats.items():
            row.update({f"stats/{key}/{name}": value.tolist() for name, value in s.items()})
        for key, s in pixel_stats.items():
            row.update({f"stats/{key}/{name}": value for name, value in as_image_stats(s).items()})
        self.result.rows.append(row)

    def abort(self) -> None:
        """End the videos' ffmpeg processes at once and let go of the data file (the folder is thrown away)."""
        self.videos.abort()
        if self._file is not None:
            with contextlib.suppress(Exception):  # (its bytes no longer matter)
                self._file.close()
            self._file = None

    def close(self) -> ShardResult:
        if self._file is not None:
            self._file.close()
        self.result.data_files = self._file_number + 1
        self.result.video_files = self.videos.finish()
        return self.result
