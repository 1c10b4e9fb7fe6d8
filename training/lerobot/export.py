"""`export_lerobot`: the episodes of simreel recordings (and ManiSkill files) as a LeRobot dataset v3.0 folder.

Episodes are taken as `simreel.training.episodes` chooses them (a replay report's verified ones by default when a
report is given), in the order of the inputs. Each episode's place in the dataset is planned up front from the
episodes' lengths (`_plan`), the episodes are cut into one run of consecutive episodes a worker (`--workers`,
`--ray`: `parallel`), and each run is streamed an episode at a time into data and video files of its own (`shard`).
One final step then gives each shard's files their numbers in the dataset and writes the metadata (info.json,
stats.json, tasks, the episodes table) once. With one worker the files are exactly those of a plain streaming
export. The folder is written under a hidden name beside OUT and takes its name only when complete
(`simreel.io.folders.staged_folder`)."""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from simreel.datasets.inputs import file_identity, shown_path
from simreel.errors import UsageError
from simreel.io.folders import check_folder_output, staged_folder
from simreel.options.checks import options_with
from simreel.training.episodes import EpisodeRef, SourceFile, chosen_episodes, episode_count
from simreel.training.features import resolve_features, same_features
from simreel.training.lerobot.frame_stats import DatasetStats
from simreel.training.lerobot.frames import FrameLayout
from simreel.training.lerobot.layout import (
    CHUNKS_SIZE,
    DATA_PATH,
    EPISODES_PATH,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_PATH,
    chunk_file,
    info_document,
    is_lerobot_dataset,
    write_json,
    write_tasks,
)
from simreel.training.lerobot.options import ExportOptions
from simreel.training.lerobot.parallel import shard_folder, split_episodes, write_shards
from simreel.training.lerobot.shard import ExportJob, PlannedEpisode, ShardResult
from simreel.training.lerobot.videos import (
    VideoFeature,
    as_image_stats,
    camera_fields,
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
                   *, progress: Callable[[int], Any] | None = None, **overrides: Any) -> ExportSummary:
    """Export the episodes of the recordings `inputs` names to the LeRobot dataset folder `out`; `options` (or its
    fields as keywords) say what it holds, which episodes, and over how many workers; `progress` is called with the
    frames of each episode (each shard with Ray) once written."""
    opts = options_with(ExportOptions, options, overrides, 'export_lerobot("demos/", "out", report="report.json")')
    inputs = [inputs] if isinstance(inputs, (str, Path)) else list(inputs)
    out = check_export_target(out, overwrite=opts.overwrite)
    choice = EpisodeChoice(report=opts.report, keep=opts.keep)
    episodes, files = chosen_episodes(inputs, choice)
    if opts.report is None:
        left_out = 0
    else:
        left_out = episode_count(list(files)) - len(episodes)
    layouts = _layouts(opts, files, episodes)
    fps = _fps(files)
    first = next(iter(layouts.values()))
    job = ExportJob(layouts, first.features, [VideoFeature(key, f.shape, fps) for key, f in first.cameras.items()], fps)
    planned = _plan(episodes, files, opts.task)
    with staged_folder(out, overwrite=opts.overwrite, looks_ours=is_lerobot_dataset, kind=_KIND) as folder:
        results = write_shards(job, split_episodes(planned, opts.workers), folder, ray=opts.ray, progress=progress)
        _place_files(folder, results, [v.key for v in job.videos])
        _write_metadata(folder, job, results, robot_type=_robot_type(files),
                        provenance=_provenance(files, episodes, opts))
    frames = sum(e.ref.length for e in planned)
    return ExportSummary(out, len(episodes), frames, fps, [f.key for f in job.features] + [v.key for v in job.videos],
                         sources=list(files), left_out=left_out)


def _plan(episodes: Sequence[EpisodeRef], files: dict[str, SourceFile], task: str | None) -> list[PlannedEpisode]:
    """Each episode's place in the dataset (its episode_index and first frame's index, from the episodes' lengths)
    and task (`task`, else its env id; task_index in the order the tasks first come)."""
    tasks: dict[str, int] = {}
    planned, first_index = [], 0
    for number, episode in enumerate(episodes):
        text = task or files[episode.path].meta.env_id
        planned.append(PlannedEpisode(episode, number, first_index, text, tasks.setdefault(text, len(tasks))))
        first_index += episode.length
    return planned


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


def _place_files(folder: Path, results: Sequence[ShardResult], video_keys: Sequence[str]) -> None:
    """Move each shard's data and video files to their numbers in the dataset (the first shard's are in place;
    each next one's follow them) and renumber its episodes' rows to match."""
    data_offset, video_offsets = 0, dict.fromkeys(video_keys, 0)
    for number, result in enumerate(results):
        source = shard_folder(folder, number)
        for n in range(result.data_files):
            _move(source / DATA_PATH.format(**chunk_file(n)), folder / DATA_PATH.format(**chunk_file(data_offset + n)))
        for key in video_keys:
            for n in range(result.video_files[key]):
                _move(source / VIDEO_PATH.format(video_key=key, **chunk_file(n)),
                      folder / VIDEO_PATH.format(video_key=key, **chunk_file(video_offsets[key] + n)))
        for row in result.rows:
            _renumber(row, "data", data_offset)
            for key in video_keys:
                _renumber(row, f"videos/{key}", video_offsets[key])
        data_offset += result.data_files
        for key in video_keys:
            video_offsets[key] += result.video_files[key]
        if source != folder:
            shutil.rmtree(source)


def _move(source: Path, target: Path) -> None:
    if source != target:
        target.parent.mkdir(parents=True, exist_ok=True)
        source.rename(target)


def _renumber(row: dict[str, Any], prefix: str, offset: int) -> None:
    """Shift the file a row points at (``<prefix>/chunk_index``, ``<prefix>/file_index``) by `offset` files."""
    local = row[f"{prefix}/chunk_index"] * CHUNKS_SIZE + row[f"{prefix}/file_index"]
    where = chunk_file(local + offset)
    row[f"{prefix}/chunk_index"], row[f"{prefix}/file_index"] = where["chunk_index"], where["file_index"]


def _write_metadata(folder: Path, job: ExportJob, results: Sequence[ShardResult], *, robot_type: str | None,
                    provenance: dict[str, Any]) -> None:
    """The one final step, once every shard is written: the episodes table, the tasks, stats.json (the episodes'
    statistics merged in their order) and info.json."""
    rows = [row for result in results for row in result.rows]
    tasks = list(dict.fromkeys(row["tasks"][0] for row in rows))
    columns = {key: [row[key] for row in rows] for key in rows[0]}
    episodes_path = folder / EPISODES_PATH.format(**chunk_file(0))
    episodes_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pydict(columns), episodes_path)
    write_tasks(folder / TASKS_PATH, tasks)
    merged = DatasetStats()
    for result in results:
        for episode in result.moments:
            merged.add(episode)
    stats = merged.document()
    stats.update({v.key: as_image_stats(stats[v.key]) for v in job.videos})
    write_json(folder / STATS_PATH, stats)
    totals = {"total_episodes": len(rows), "total_frames": sum(row["length"] for row in rows),
              "total_tasks": len(tasks)}
    write_json(folder / INFO_PATH, info_document(fps=job.fps, features=[*job.features, *job.videos], totals=totals,
                                                 robot_type=robot_type, provenance=provenance))
