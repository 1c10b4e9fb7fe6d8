"""The episodes a session draws: the recorded one and, with ``--compare``, the one compared with it (its replay, its
conversion or another recording of the task), read from their files.

An `EpisodeRun` keeps its file open and holds a summary of the episode: its per-step fields (actions, rewards,
flags, info, contact forces) and its controller states, what the events of a whole episode (`simreel.verdicts.divergence`:
grasps, contacts, controller jumps) and the layout are found from. The rest, the states, body poses and
observations (camera frames) that make up most of a long episode, is read a block of rows at a time from
`EpisodeRun.rows` whenever it is compared or logged.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simreel.errors import RecordingFileError, StorageError, ViewError
from simreel.formats import EpisodeReader, open_reader
from simreel.formats.base import EpisodeRows, block_rows
from simreel.model.blocks import StepBlock, join_blocks
from simreel.model.episode import Episode
from simreel.model.fields import FieldSpec
from simreel.model.meta import RecordingMeta
from simreel.viewers.compare import compared_role

__all__ = ["EpisodeRun", "read_run", "read_compare", "Source"]

Source = str | Path | EpisodeReader
"""A recording to read: a path (.h5 or .mcap) or an open reader."""


@dataclass
class EpisodeRun:
    """One episode to draw: the recorded one or the one compared with it."""

    label: str
    """``<file name> episode <index>``, with its `role` in brackets when it has one: ``replayed.h5 episode 0 (replay)``."""
    meta: RecordingMeta
    episode: Episode
    """The episode's summary (`summary`): per-step fields and controller states; no observations, body poses or other
    states (read in blocks from `rows`)."""
    file_name: str
    rows: EpisodeRows
    """The episode in its file, read a block of rows at a time."""
    path: Path
    """The file the episode is read from."""
    reader: EpisodeReader | None = None
    """The reader this run opened (closed by `close`); None when the caller's."""
    role: str = ""
    """What a compared run is to the recording (`simreel.viewers.compare.compared_role`): ``replay``,
    ``conversion``, or "" (the recording itself, or another recording of the task)."""

    @property
    def subject(self) -> str:
        """What the output calls a compared run: its `role`, else its file name (``second.h5 diverges at step 3``),
        so a second recording of the task is never called a replay."""
        return self.role or self.file_name

    @property
    def state_keys(self) -> set[str]:
        """The state keys the file holds (``actors/cube``, ...)."""
        return {f.name.split("/", 1)[1] for f in self.rows.fields if f.name.startswith("env_states/")}

    def row_blocks(self, rows: int | None = None) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
        """(first state row, flat field arrays) of the whole episode, in order: state row 0 (the reset: per-state
        fields only), then blocks of `rows` steps (None: `block_rows` of the file), each with its per-step rows and
        the per-state rows after them, so every array of a block starting at state row r covers rows r, r + 1, ...
        States the file lacks but the summary holds (`states_by_stepping`) are sliced from the summary."""
        extra = {f"env_states/{k}": a for k, a in self.episode.env_states.items() if k not in self.state_keys}
        yield 0, {**self.rows.reset().arrays, **{k: a[:1] for k, a in extra.items()}}
        for start, block in self.rows.blocks(rows or block_rows(self.rows.fields)):
            yield start + 1, {**block.arrays, **{k: a[start + 1 : start + 1 + block.rows] for k, a in extra.items()}}

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
            self.reader = None


def _open(source: Source) -> tuple[EpisodeReader, bool]:
    if isinstance(source, EpisodeReader):
        return source, False
    return open_reader(source), True


def read_run(source: Source, index: int | None, *, role: str = "") -> EpisodeRun:
    """Episode `index` of `source` (None: its first episode); `role` (`EpisodeRun.role`) is added to the label.
    The run keeps a reader it opened until `EpisodeRun.close`."""
    reader, owned = _open(source)
    try:
        if not reader.episodes:
            raise RecordingFileError(reader.path, "holds no committed episode to view")
        if index is None:
            index = reader.episodes[0].index
        reader.episode_meta(index)  # a clear error naming the episodes there are, or the damaged ones
        try:
            rows = reader.open_episode(index)
            episode = summary(rows)
        except StorageError:
            raise
        except RecordingFileError as e:
            raise _damaged_episode(reader, index, e.problem) from None
    except BaseException:
        if owned:
            reader.close()
        raise
    name = Path(reader.path).name
    label = f"{name} episode {index}" + (f" ({role})" if role else "")
    return EpisodeRun(label, reader.meta, episode, name, rows, Path(reader.path), reader if owned else None, role)


def read_compare(compare: Source, recorded: EpisodeRun, *, option: str = "--episode") -> EpisodeRun:
    """The episode of `compare` to draw beside `recorded`: its episode of the same index (``simreel replay -o`` and
    ``simreel convert`` keep the recording's indices), never another: a different episode's replay would be judged as
    this one's. `option` is the one that picks episodes, named in the error when `compare` lacks this index. Its
    `EpisodeRun.role` says whether `compare` is a replay or a conversion of the recording."""
    reader, owned = _open(compare)
    try:
        index = recorded.episode.meta.index
        have = [m.index for m in reader.episodes]
        if index not in have:
            raise ViewError(
                f"--compare {reader.path}: no episode {index} to compare with episode {index} of "
                f"{recorded.file_name} (it has {', '.join(map(str, have)) or 'none'}); pick an episode it has with "
                f"{option}, or replay episode {index} with `simreel replay -o`"
            )
        run = read_run(reader, index, role=compared_role(reader.meta, recorded.meta, recorded.path))
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


def _in_summary(field: FieldSpec) -> bool:
    if field.name.startswith("env_states/"):
        return field.name.startswith("env_states/controller/")
    return not field.per_state


def summary(rows: EpisodeRows) -> Episode:
    """The episode's per-step fields and controller states, read a block at a time (`EpisodeRun.episode`)."""
    fields = [f for f in rows.fields if _in_summary(f)]
    names = [f.name for f in fields]
    steps = [StepBlock.of({n: block[n] for n in names}) for _, block in rows.blocks()]
    reset = rows.reset()
    reset = StepBlock.of({n: reset[n] for n in names if n in reset.arrays})
    return Episode.from_fields(rows.meta, join_blocks(fields, reset, steps))


def _check_comparable(run: EpisodeRun, recorded: EpisodeRun) -> None:
    """`ViewError` unless `run` can be drawn beside `recorded` (``view --compare``, ``video --compare``):
    a recording of the same env, with states in common (restored into the recording's env, another env's states
    would be drawn as if they were its own)."""
    if run.meta.env_id != recorded.meta.env_id:
        raise ViewError(
            f"--compare {run.label}: it is a recording of {run.meta.env_id}, not of {recorded.meta.env_id}; "
            f"compare a replay or another recording of {recorded.meta.env_id}"
        )
    if not run.state_keys & recorded.state_keys:
        raise ViewError(f"--compare {run.label}: no state key in common with {recorded.label}")


def _damaged_episode(reader: EpisodeReader, index: int, problem: str) -> RecordingFileError:
    """The error for episode `index` of `reader`, whose data is damaged (`problem`: what is wrong), and what to do."""
    return RecordingFileError(reader.path, f"episode {index} is damaged ({problem}); {reader.recover_hint()}")
