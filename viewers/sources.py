"""The episodes a session draws: the recorded one and, with ``--compare``, its replay, read from their files."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from simreel.episode import Episode, RecordingMeta
from simreel.errors import RecordingFileError, ViewError
from simreel.formats import EpisodeReader, open_reader

__all__ = ["EpisodeRun", "read_run", "read_compare", "Source"]

Source = str | Path | EpisodeReader
"""A recording to read: a path (.h5 or .mcap) or an open reader."""


@dataclass
class EpisodeRun:
    """One episode to draw: the recorded one or the replayed one."""

    label: str
    meta: RecordingMeta
    episode: Episode
    file_name: str


def _open(source: Source) -> tuple[EpisodeReader, bool]:
    if isinstance(source, EpisodeReader):
        return source, False
    return open_reader(source), True


def read_run(source: Source, index: int | None, *, role: str = "") -> EpisodeRun:
    """Episode `index` of `source` (None: its first episode); `role` is added to the label (``replayed``)."""
    reader, owned = _open(source)
    try:
        if not reader.episodes:
            raise RecordingFileError(reader.path, "holds no committed episode to view")
        if index is None:
            index = reader.episodes[0].index
        reader.episode_meta(index)  # a clear error naming the episodes there are
        episode = reader.read_episode(index)
        name = Path(reader.path).name
        label = f"{name} episode {index}" + (f" ({role})" if role else "")
        return EpisodeRun(label, reader.meta, episode, name)
    finally:
        if owned:
            reader.close()


def read_compare(compare: Source, recorded: EpisodeRun) -> EpisodeRun:
    """The replay of `recorded` in `compare`: its episode of the same index, or its only episode."""
    reader, owned = _open(compare)
    try:
        index = recorded.episode.meta.index
        have = [m.index for m in reader.episodes]
        if index not in have:
            if len(have) != 1:
                raise ViewError(
                    f"--compare {reader.path}: no episode {index} to compare with episode {index} of the recording "
                    f"(it has {', '.join(map(str, have)) or 'none'}); replay that episode with `simreel replay -o`"
                )
            index = have[0]
        run = read_run(reader, index, role="replayed")
    finally:
        if owned:
            reader.close()
    if run.meta.env_id != recorded.meta.env_id:
        raise ViewError(
            f"--compare {run.label}: it is a recording of {run.meta.env_id}, not of {recorded.meta.env_id}; "
            "compare a replay of the same recording"
        )
    if not set(run.episode.env_states) & set(recorded.episode.env_states):
        raise ViewError(f"--compare {run.label}: no state key in common with {recorded.label}")
    return run
