"""The episodes a session draws: the recorded one and, with ``--compare``, its replay, read from their files.

An `EpisodeRun` keeps its file open and holds the episode without its observations (`EpisodeRows.episode` with
``obs=False``: states, actions, rewards, flags, info, contacts, body poses); the observations (camera frames) are
read a block of rows at a time from `EpisodeRun.rows`, whenever they are compared or logged.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from simreel.episode import Episode, FieldSpec, RecordingMeta, StepBlock
from simreel.errors import RecordingFileError, ViewError
from simreel.formats import EpisodeReader, open_reader
from simreel.formats.base import EpisodeRows, block_rows

__all__ = ["EpisodeRun", "read_run", "read_compare", "Source"]

Source = str | Path | EpisodeReader
"""A recording to read: a path (.h5 or .mcap) or an open reader."""


@dataclass
class EpisodeRun:
    """One episode to draw: the recorded one or the replayed one."""

    label: str
    meta: RecordingMeta
    episode: Episode
    """The episode without its observations (``episode.obs`` is empty): those are read in blocks from `rows`."""
    file_name: str
    rows: EpisodeRows
    """The episode in its file, read a block of rows at a time."""
    reader: EpisodeReader | None = None
    """The reader this run opened (closed by `close`); None when the caller's."""

    @property
    def obs_fields(self) -> list[FieldSpec]:
        return [f for f in self.rows.fields if f.name.startswith("obs/")]

    def blocks(self, steps: int, rows: int | None = None) -> Iterator[tuple[int, StepBlock]]:
        """(first step, block) of the first `steps` steps, `rows` steps a block (None: `block_rows` of the file)."""
        rows = rows or block_rows(self.rows.fields)
        for start in range(0, steps, rows):
            yield start, self.rows.steps(start, min(steps, start + rows))

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
            self.reader = None


def _open(source: Source) -> tuple[EpisodeReader, bool]:
    if isinstance(source, EpisodeReader):
        return source, False
    return open_reader(source), True


def read_run(source: Source, index: int | None, *, role: str = "") -> EpisodeRun:
    """Episode `index` of `source` (None: its first episode); `role` is added to the label (``replayed``).
    The run keeps a reader it opened until `EpisodeRun.close`."""
    reader, owned = _open(source)
    try:
        if not reader.episodes:
            raise RecordingFileError(reader.path, "holds no committed episode to view")
        if index is None:
            index = reader.episodes[0].index
        reader.episode_meta(index)  # a clear error naming the episodes there are
        rows = reader.open_episode(index)
        episode = rows.episode(obs=False)
    except BaseException:
        if owned:
            reader.close()
        raise
    name = Path(reader.path).name
    label = f"{name} episode {index}" + (f" ({role})" if role else "")
    return EpisodeRun(label, reader.meta, episode, name, rows, reader if owned else None)


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
    except BaseException:
        if owned:
            reader.close()
        raise
    run.reader = reader if owned else None
    try:
        _check_comparable(run, recorded)
    except BaseException:
        run.close()
        raise
    return run


def _check_comparable(run: EpisodeRun, recorded: EpisodeRun) -> None:
    if run.meta.env_id != recorded.meta.env_id:
        raise ViewError(
            f"--compare {run.label}: it is a recording of {run.meta.env_id}, not of {recorded.meta.env_id}; "
            "compare a replay of the same recording"
        )
    if not set(run.episode.env_states) & set(recorded.episode.env_states):
        raise ViewError(f"--compare {run.label}: no state key in common with {recorded.label}")
