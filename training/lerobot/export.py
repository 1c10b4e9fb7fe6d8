"""`export_lerobot`: the episodes of simreel recordings (and ManiSkill files) as a LeRobot dataset v3.0 folder.

Episodes are taken as `simreel.training.episodes` chooses them (a replay report's verified ones by default when a
report is given), in the order of the inputs, and streamed one at a time: each episode's frames (`frames`) are
appended to the current data file as one row group (a new file once it reaches ~100 MB), its row of the episodes
table and its statistics are kept, and the metadata (info.json, stats.json, tasks, the episodes table) are written
once at the end. The folder is written under a hidden name beside OUT and takes its name only when complete
(`simreel.io.folders.staged_folder`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from simreel.datasets.inputs import file_identity, shown_path
from simreel.errors import UsageError
from simreel.formats import open_reader
from simreel.io.folders import check_folder_output, staged_folder
from simreel.options.checks import options_with
from simreel.training.episodes import EpisodeRef, SourceFile, chosen_episodes
from simreel.training.features import resolve_features, same_features
from simreel.training.lerobot.frame_stats import DatasetStats, episode_stats
from simreel.training.lerobot.frames import FrameLayout
from simreel.training.lerobot.layout import (
    DATA_FILE_MB,
    DATA_PATH,
    EPISODES_PATH,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    arrow_column,
    chunk_file,
    info_document,
    is_lerobot_dataset,
    write_json,
    write_tasks,
)
from simreel.training.lerobot.options import ExportOptions
from simreel.training.lerobot.videos import (
    CameraVideos,
    VideoFeature,
    as_image_stats,
    camera_fields,
    image_pixels,
)
from simreel.training.options import EpisodeChoice

__all__ = ["export_lerobot", "ExportSummary", "check_export_target"]

_KIND = "LeRobot dataset"


@dataclass
class ExportSummary:
    """What an export wrote: the folder, its episodes and frames, the fps, the features, the files read."""

    path: Path
    episodes: int
    frames: int
    fps: float
    features: list[str]
    sources: list[str] = field(default_factory=list)
    left_out: int = 0
    """Episodes of the inputs the report's verdicts left out."""

    def summary(self) -> str:
        kept = f" ({self.left_out} left out by the report's verdicts)" if self.left_out else ""
        return (f"exported {self.episodes} episode(s), {self.frames} frames at {self.fps:g} fps{kept} from "
                f"{len(self.sources)} recording(s) to {shown_path(self.path)} (LeRobot dataset v3.0: "
                f"{', '.join(self.features)})")


def check_export_target(out: str | Path, *, overwrite: bool) -> Path:
    """`UsageError` unless a LeRobot dataset can be written at `out` (`check_folder_output`); touches nothing."""
    return check_folder_output(out, overwrite=overwrite, looks_ours=is_lerobot_dataset, kind=_KIND)


def export_lerobot(inputs: str | Path | Sequence[str | Path], out: str | Path, options: ExportOptions | None = None,
                   **overrides: Any) -> ExportSummary:
    """Export the episodes of the recordings `inputs` names to the LeRobot dataset folder `out`; `options` (or its
    fields as keywords) say what it holds and which episodes."""
    opts = options_with(ExportOptions, options, overrides, 'export_lerobot("demos/", "out", report="report.json")')
    inputs = [inputs] if isinstance(inputs, (str, Path)) else list(inputs)
    out = check_export_target(out, overwrite=opts.overwrite)
    choice = EpisodeChoice(report=opts.report, keep=opts.keep)
    episodes, files = chosen_episodes(inputs, choice)
    if opts.report is None:
        left_out = 0
    else:
        left_out = sum(len(open_reader(p).episodes) for p in files) - len(episodes)
    layouts = _layouts(opts, files, episodes)
    fps = _fps(files)
    with staged_folder(out, overwrite=opts.overwrite, looks_ours=is_lerobot_dataset, kind=_KIND) as folder:
        first = next(iter(layouts.values()))
        videos = [VideoFeature(key, f.shape, fps) for key, f in first.cameras.items()]
        writer = _Writer(folder, first.features, CameraVideos(folder, videos, fps))
        tasks: dict[str, int] = {}
        try:
            for number, episode in enumerate(episodes):
                task = opts.task or files[episode.path].meta.env_id
                task_index = tasks.setdefault(task, len(tasks))
                with open_reader(episode.path) as reader:
                    frames = layouts[episode.path].frames(reader.open_episode(episode.index), fps=fps,
                                                          episode_index=number, first_index=writer.frames,
                                                          task_index=task_index)
                writer.episode(number, episode, task, frames)
        except BaseException:
            writer.videos.abort()  # no ffmpeg left running
            raise
        writer.finish(fps=fps, tasks=list(tasks), robot_type=_robot_type(files),
                      provenance=_provenance(files, episodes, opts))
    return ExportSummary(out, len(episodes), writer.frames, fps,
                         [f.key for f in writer.features] + [f.key for f in writer.videos.features],
                         sources=list(files), left_out=left_out)


def _layouts(opts: ExportOptions, files: dict[str, SourceFile], episodes: Sequence[EpisodeRef]
             ) -> dict[str, FrameLayout]:
    """Each file's frame layout; the same columns in every file (`same_features`)."""
    first: tuple[str, list] | None = None
    out = {}
    for path in dict.fromkeys(e.path for e in episodes):
        index = next(e.index for e in episodes if e.path == path)
        fields = files[path].fields
        state_names = opts.state or (("obs",) if any(f.name.startswith("obs/") for f in fields) else ("env_states",))
        state = resolve_features(state_names, fields, path=path, episode=index)
        cameras = camera_fields(fields)
        if not opts.state:  # camera frames go to videos, not into the state
            state = [f for f in state if f not in cameras]
        if any(not f.per_state for f in state):
            raise UsageError(f"--state {','.join(state_names)}: {', '.join(f.name for f in state if not f.per_state)} "
                             "is one row a step, not a state; name obs/... or env_states/... fields")
        extras = resolve_features(opts.extras, fields, path=path, episode=index) if opts.extras else []
        chosen = [*state, *extras, *cameras, *(f for f in fields if f.name == "actions")]
        if first is None:
            first = (path, chosen)
        else:
            same_features(chosen, first[1], path=path, first_path=first[0])
        out[path] = FrameLayout(state, fields, extras, cameras)
    return out


def _fps(files: dict[str, SourceFile]) -> float:
    """The frame rate: the env's control frequency, the same in every file."""
    rates = {path: f.meta.control_freq for path, f in files.items()}
    if None in rates.values():
        path = next(p for p, r in rates.items() if r is None)
        raise UsageError(f"{path}: the recording does not say its control frequency, so the frames have no rate; "
                         "record it with simreel (ManiSkill's files lack it)")
    if len(set(rates.values())) > 1:
        raise UsageError(f"the recordings run at different control frequencies ({', '.join(f'{shown_path(p)}: {r:g} Hz' for p, r in rates.items())}); "
                         "a LeRobot dataset has one fps: export them separately")
    return float(next(iter(rates.values())))


def _robot_type(files: dict[str, SourceFile]) -> str | None:
    robots = {str(f.meta.env_kwargs.get("robot_uids")) for f in files.values() if f.meta.env_kwargs.get("robot_uids")}
    return robots.pop() if len(robots) == 1 else None


def _provenance(files: dict[str, SourceFile], episodes: Sequence[EpisodeRef], opts: ExportOptions) -> dict[str, Any]:
    sources = []
    for path, f in files.items():
        size, mtime_ns = file_identity(path)
        sources.append({"path": path, "size": size, "mtime_ns": mtime_ns, "env_id": f.meta.env_id,
                        "recording_id": f.meta.recording_id, "control_mode": f.meta.control_mode,
                        "obs_mode": f.meta.obs_mode, "episodes": [e.index for e in episodes if e.path == path]})
    return {"sources": sources, "report": None if opts.report is None else str(Path(opts.report).resolve()),
            "keep": list(opts.keep) if opts.report is not None else None, "command": opts.command}


class _Writer:
    """The data files (one row group an episode, a new file past ~100 MB), the episodes table and the stats."""

    def __init__(self, folder: Path, features: Sequence[Any], videos: CameraVideos) -> None:
        self.folder, self.features, self.videos = folder, list(features), videos
        self.schema = pa.schema([pa.field(f.key, f.arrow_type(), nullable=False) for f in self.features])
        self.frames = 0
        self._file_number = -1
        self._file: pq.ParquetWriter | None = None
        self._file_bytes = 0
        self._episode_rows: list[dict[str, Any]] = []
        self.stats = DatasetStats()

    def _data_file(self, incoming: int) -> dict[str, int]:
        if self._file is None or self._file_bytes + incoming > DATA_FILE_MB * 2**20:
            if self._file is not None:
                self._file.close()
            self._file_number += 1
            path = self.folder / DATA_PATH.format(**chunk_file(self._file_number))
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file, self._file_bytes = pq.ParquetWriter(path, self.schema), 0
        return chunk_file(self._file_number)

    def episode(self, number: int, episode: EpisodeRef, task: str, frames: dict[str, np.ndarray]) -> None:
        images = {f.key: frames.pop(f.key) for f in self.videos.features}
        table = pa.table([arrow_column(f, frames[f.key]) for f in self.features], schema=self.schema)
        where = self._data_file(table.nbytes)
        self._file.write_table(table)
        self._file_bytes += table.nbytes
        stats = {key: episode_stats(values) for key, values in frames.items()}
        self.stats.add(frames, stats)
        pixels = {key: image_pixels(values) for key, values in images.items()}
        pixel_stats = {key: episode_stats(values) for key, values in pixels.items()}
        self.stats.add(pixels, pixel_stats)
        length = len(frames["index"])
        row = {"episode_index": number, "tasks": [task], "length": length,
               "data/chunk_index": where["chunk_index"], "data/file_index": where["file_index"],
               "dataset_from_index": self.frames, "dataset_to_index": self.frames + length,
               "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
               "simreel/source_file": episode.path, "simreel/source_episode": episode.index,
               "simreel/verdict": episode.verdict, **self.videos.episode(images)}
        for key, s in stats.items():
            row.update({f"stats/{key}/{name}": value.tolist() for name, value in s.items()})
        for key, s in pixel_stats.items():
            row.update({f"stats/{key}/{name}": value for name, value in as_image_stats(s).items()})
        self._episode_rows.append(row)
        self.frames += length

    def finish(self, *, fps: float, tasks: list[str], robot_type: str | None, provenance: dict[str, Any]) -> None:
        if self._file is not None:
            self._file.close()
        self.videos.finish()
        columns = {key: [row[key] for row in self._episode_rows] for key in self._episode_rows[0]}
        episodes_path = self.folder / EPISODES_PATH.format(**chunk_file(0))
        episodes_path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.Table.from_pydict(columns), episodes_path)
        write_tasks(self.folder / TASKS_PATH, tasks)
        stats = self.stats.document()
        stats.update({f.key: as_image_stats(stats[f.key]) for f in self.videos.features})
        write_json(self.folder / STATS_PATH, stats)
        totals = {"total_episodes": len(self._episode_rows), "total_frames": self.frames, "total_tasks": len(tasks)}
        write_json(self.folder / INFO_PATH, info_document(fps=fps, features=[*self.features, *self.videos.features],
                                                          totals=totals,
                                                          robot_type=robot_type, provenance=provenance))
