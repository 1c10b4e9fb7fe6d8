"""The reader/writer interface every recording format implements.

Writing streams: `EpisodeWriter.begin_episode` opens an `EpisodeSink` per running episode (one per
parallel env) with the episode's reset row, the recorder appends `StepBlock`s of a few hundred steps, and
`commit` makes the episode durable — after `commit` returns, a `kill -9` of the process must not lose it.
Every block is checked against the recording's field table (`simreel.model.fields.episode_fields`) on its way
in. A writer holds its file's lock for its whole life and writes where `simreel.io.staging` says (a
recording that replaces another is moved over it only by `close`); `abort` drops what it wrote instead.
Reading is per episode, and an episode is read in blocks of rows (`EpisodeReader.open_episode` gives its
`EpisodeRows`), so neither a large file nor a long episode has to fit in memory; `read_episode` puts one whole
episode together from the same blocks. A reader names what it could not read (`damaged`), what never finished
(`unfinished`) and anything else a user should know about the file (`notes`).
"""

from __future__ import annotations

import errno
import inspect
import math
import shutil
from abc import ABC, abstractmethod
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar

import numpy as np

from simreel.errors import EpisodeLayoutError, MetadataError, RecordingFileError, StorageError, UsageError
from simreel.io.durable import is_storage_error, storage_error
from simreel.io.lock import being_written
from simreel.io.paths import is_symlink_loop, read_problem
from simreel.io.replacement import refuse_interrupted
from simreel.io.staging import refuse_kept_recording
from simreel.io.targets import check_output
from simreel.model.blocks import StepBlock, join_blocks
from simreel.model.episode import Episode
from simreel.model.fields import FieldSpec, episode_fields
from simreel.model.geometry import SceneGeometry
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.options.checks import is_whole_number

__all__ = ["EpisodeSink", "EpisodeWriter", "EpisodeReader", "EpisodeRows", "BLOCK_BYTES", "block_rows"]

BLOCK_BYTES = 4 << 20
"""About how many bytes of an episode one block of rows holds: 85 steps of 128x128 rgb camera frames (49 KB each),
thousands of steps of a state-only recording (`block_rows`)."""
_MAX_BLOCK_ROWS = 4096
"""At most this many steps per block (state-only rows are small; longer blocks gain nothing)."""


def not_a_file(path: Path) -> RecordingFileError:
    """The error for a recording path that is not a regular file: missing, a symbolic link loop, a folder, or a
    device, pipe or socket. The first three in the words a refused open of them gets (`read_problem`)."""
    if path.exists() and not path.is_dir():
        return RecordingFileError(path, "not a regular file")
    # a symbolic link loop, which `is_file` and `exists` take for a missing file, first
    code = errno.ELOOP if is_symlink_loop(path) else errno.EISDIR if path.is_dir() else errno.ENOENT
    return RecordingFileError(path, read_problem(code))


def block_rows(fields: Sequence[FieldSpec], budget: int = BLOCK_BYTES) -> int:
    """Steps per block of an episode with `fields`: as many as fit in `budget` bytes, between 1 and 4096."""
    row = sum(np.dtype(f.dtype).itemsize * int(np.prod(f.shape, dtype=np.int64)) for f in fields)
    return int(min(_MAX_BLOCK_ROWS, max(1, budget // max(1, row))))


class EpisodeSink(ABC):
    """One episode being written. Use `append` any number of times, then `commit` or `discard`; after either it
    takes nothing more (`check_running`), and a commit must give this episode's metadata (`check_commit`)."""

    index: int
    """The index of the episode (`EpisodeMeta.index` given to `begin_episode`)."""
    steps: int = 0
    """The steps appended so far."""
    ended = False
    """Committed or discarded."""

    def check_running(self) -> None:
        """`UsageError` once the episode was committed or discarded: what a sink took after that would be lost (an
        append), or written again (a commit)."""
        if self.ended:
            raise UsageError(f"episode {self.index} was already committed or discarded; begin_episode another one")

    def check_commit(self, meta: EpisodeMeta) -> None:
        """`UsageError` unless the episode is running and `meta` is its own: its index (another would file these
        steps under another episode) and the steps appended as its length (readers go by it)."""
        self.check_running()
        if meta.index != self.index:
            raise UsageError(f"commit of episode {meta.index} on the sink of episode {self.index}; commit each "
                             "episode with its own EpisodeMeta")
        if meta.length != self.steps:
            raise UsageError(f"episode {self.index}: committed with length {meta.length}, but {self.steps} step(s) "
                             f"were appended; give EpisodeMeta(length={self.steps})")

    @abstractmethod
    def append(self, block: StepBlock) -> None:
        """Write the block; must not keep references to its arrays (they are reused buffers)."""

    @abstractmethod
    def commit(self, meta: EpisodeMeta) -> None:
        """Make the episode durable in the file, with its final metadata (length, success, ...)."""

    @abstractmethod
    def discard(self) -> None:
        """Drop the episode (e.g. a reset before any step); nothing of it stays on disk."""

    def finish(self, meta: EpisodeMeta, last: StepBlock | None = None) -> None:
        """Append `last`, the episode's steps not yet appended (if any), and commit: what a recorder does when an
        episode ends, in one call (a writer process gets it as one message)."""
        if last is not None:
            self.append(last)
        self.commit(meta)


class EpisodeWriter(ABC):
    """Writes one recording file. A context manager; `close` commits nothing that was not committed."""

    records_poses_by_default: ClassVar[bool] = False
    """Whether a recorder writing this format records body poses unless told otherwise."""
    writes_scene: ClassVar[bool] = False
    """Whether this format keeps what the scene looks like (`write_scene`)."""
    converts_captures: ClassVar[bool] = False
    """Whether the writer takes blocks whose rows are still captures (`StepBlock.captured`) and converts them off the
    caller's time (`simreel.recorders.writer_process.ProcessWriter`, in its child); a writer in the caller's process
    would only convert them there, so a recorder converts them itself, a block at a time."""

    def __init__(self, path: str | Path, meta: RecordingMeta) -> None:
        self.path = Path(path)
        self.meta = self.checked_meta(meta, RecordingMeta)
        self.fields = episode_fields(meta)
        """The field table every episode's blocks are checked against."""
        self.reset_fields = [f for f in self.fields if f.per_state]
        """The fields of an episode's reset row."""

    def checked_meta(self, meta: Any, kind: type) -> Any:
        """`meta` (a `RecordingMeta` or `EpisodeMeta`, `kind`) as a reader of the file will read it: `UsageError`
        naming the file and the field where a reader would refuse it (`from_json`: the file or the episode would be
        written and then never read), before anything is written. Numpy numbers become Python's, as in the file."""
        try:
            as_read = meta.to_json()  # values of JSON types only, as `json.loads` of the file's text gives them
        except (TypeError, ValueError) as e:
            raise UsageError(f"{self.path}: {_METADATA[kind]} does not convert to JSON: {e}") from None
        try:
            checked = kind.from_json(as_read)
            if kind is RecordingMeta:
                _check_rates(checked)
        except MetadataError as e:
            raise UsageError(f"{self.path}: {e}; give a value of that type") from None
        return checked

    @classmethod
    def side_paths(cls, path: Path) -> list[Path]:
        """Files and folders this format writes beside the recording `path` (none unless a format has some)."""
        return []

    @classmethod
    def option_names(cls) -> list[str]:
        """The keyword options this writer takes besides `overwrite` (`open_writer`'s ``**options``), read from its
        signature."""
        parameters = inspect.signature(cls.__init__).parameters.values()
        return [p.name for p in parameters if p.kind is p.KEYWORD_ONLY and p.name != "overwrite"]

    @classmethod
    @abstractmethod
    def check_options(cls, **options: Any) -> None:
        """`UsageError` for a value of an option (`option_names`) this writer refuses, touching nothing: the
        writer's own rule, asked before anything is created or started (`simreel.formats.check_writer_options`)."""

    @classmethod
    def check_target(cls, path: Path, *, overwrite: bool) -> None:
        """Raise `UsageError` if a new recording cannot go to `path` (`simreel.io.targets.check_output`,
        with this format's side paths, or another writer holds it). Cheap: touches nothing."""
        check_output(path, overwrite=overwrite, side_paths=cls.side_paths(path))
        refuse_interrupted(path)
        if being_written(path):
            raise UsageError(f"{path} is being written by another recording; choose another file, or wait until "
                             "that recording has finished")
        refuse_kept_recording(path)

    @classmethod
    def remove(cls, path: Path) -> None:
        """Delete the recording `path` and its side paths; those that do not exist are skipped."""
        path.unlink(missing_ok=True)
        for side in cls.side_paths(path):
            if side.is_dir() and not side.is_symlink():
                shutil.rmtree(side, ignore_errors=True)
            else:
                side.unlink(missing_ok=True)

    @abstractmethod
    def begin_episode(self, meta: EpisodeMeta, reset: StepBlock) -> EpisodeSink:
        """Start an episode whose state after reset is `reset`: one row of every per-state field
        (`env_states/...`, `obs/...` and `body_poses` as the recording's field table lists them)."""

    def reset_arrays(self, meta: EpisodeMeta, reset: StepBlock) -> dict[str, np.ndarray]:
        """The arrays of `reset` as episode `meta.index`'s reset row: `EpisodeLayoutError` unless it is one row of
        every per-state field (`StepBlock.conform`); more rows, or none, would not be the episode's (T + 1) rows."""
        if reset.rows != 1 and self.reset_fields:
            raise EpisodeLayoutError(f"episode {meta.index}: the reset block has {reset.rows} rows, expected 1 (the "
                                     "state right after the reset)")
        return reset.converted().conform(self.reset_fields, episode=meta.index)

    def write_episode(self, episode: Episode) -> None:
        """Write a whole in-memory episode (one a user made or edited; simreel's own copies use `write_rows`)."""
        episode.check_shapes()
        sink = self.begin_episode(episode.meta, episode.reset_block())
        if episode.length:
            sink.append(episode.steps_block())
        sink.commit(episode.meta)

    def write_rows(self, rows: EpisodeRows) -> None:
        """Write an episode read from a file a block of rows at a time (`convert`, `merge`, `filter`, `recover`):
        it is read one block at a time (the writer may hold a few MiB of it before its commit). A block that fails
        to read discards what was begun of the episode and raises."""
        sink = self.begin_episode(rows.meta, rows.reset())
        try:
            for _, block in rows.blocks():
                sink.append(block)
        except BaseException:
            sink.discard()
            raise
        sink.commit(rows.meta)

    committed: list[EpisodeMeta]
    _failed: StorageError | None = None
    """The storage error that stopped the writer (every later write raises it again)."""
    _closed = False

    def guard(self, write: Callable[[], Any], lost: str = "") -> Any:
        """Run `write` (a write of this recording); a write the storage refuses (full, read-only, ...) stops the
        writer with the one-line `StorageError` (`lost`: what that write lost)."""
        self._check_usable()
        try:
            return write()
        except OSError as e:
            if not is_storage_error(e):
                raise
            raise self._stop(e, lost) from None

    def _check_usable(self) -> None:
        if self._failed is not None:
            raise self._failed
        if self._closed:
            raise UsageError(f"{self.path} is closed")

    def _stop(self, e: OSError, lost: str = "") -> StorageError:
        """Stop the writer after the storage refused a write; returns the error to raise. A format extends it to
        keep what it still holds in memory from reaching the file."""
        self._failed = storage_error(self.path, e, committed=len(self.committed), lost=lost,
                                     readable=self._where_readable)
        return self._failed

    @property
    def _where_readable(self) -> str:
        """How the episodes committed before a failed write stay readable, for its error ("" when as they are)."""
        return ""

    def write_scene(self, geometry: SceneGeometry) -> None:  # noqa: B027 - optional hook
        """What the bodies of sub-scene `geometry.env_idx` look like, from its next episode on, for viewers that read
        the file without simreel (the MCAP format draws them; the others keep nothing of it: simreel's own viewer
        reads the geometry from the rebuilt env)."""

    def checkpoint(self) -> None:  # noqa: B027 - optional hook
        """Mark what `settle` waits for: everything handed to the writer so far (a writer that writes elsewhere starts
        on it now: `simreel.recorders.writer_process`)."""

    def settle(self) -> None:  # noqa: B027 - optional hook
        """Wait until everything handed to the writer up to the last `checkpoint` is written. A writer in the caller's
        process writes as it is called, so there is nothing to wait for (`simreel.recorders.writer_process` has a writer
        that does wait)."""

    @abstractmethod
    def close(self, *, replace: bool = True) -> None:
        """Finish the file (a staged recording replaces the old one now) and give up its lock. `replace=False`: the
        recording stopped before it was complete, so a staged one stays beside the old one, which stays as it was
        (`simreel.io.staging`)."""

    @abstractmethod
    def abort(self) -> None:
        """Drop the whole recording instead of finishing it: a new file is removed, a staged one too (an old
        recording it was to replace stays as it was). For a copy that failed half way."""

    def __enter__(self) -> EpisodeWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


_METADATA = {RecordingMeta: "recording metadata", EpisodeMeta: "episode metadata"}


def _check_rates(meta: RecordingMeta) -> None:
    """`MetadataError` unless the recording's control and sim frequencies are numbers > 0 (or unknown): a time axis
    (MCAP's log time) and replay's sim time are made of them."""
    for name in ("control_freq", "sim_freq"):
        value = getattr(meta, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise MetadataError(f"recording metadata: {name} is {value!r}, expected a number > 0 or None")


class EpisodeRows(ABC):
    """One episode of a recording, read a block of rows at a time, in the writers' convention: the reset row (row 0
    of the per-state fields) and blocks of steps (per-step rows t, and per-state rows t + 1: the states after those
    steps). Made by `EpisodeReader.open_episode`, which has checked what can be checked without reading the data
    (the fields' names, dtypes, shapes and row counts); every block read is checked as the format allows (HDF5
    chunk checksums, MCAP chunk CRCs) and raises `RecordingFileError` naming the episode when it fails."""

    def __init__(self, meta: EpisodeMeta, fields: Sequence[FieldSpec]) -> None:
        self.meta = meta
        """The episode's metadata; `length` is the number of steps the file holds."""
        self.fields = list(fields)

    @property
    def length(self) -> int:
        return self.meta.length

    @abstractmethod
    def reset(self) -> StepBlock:
        """Row 0 of the per-state fields: the episode right after its reset."""

    @abstractmethod
    def steps(self, start: int, stop: int) -> StepBlock:
        """Steps `start`..`stop - 1`: their per-step rows and the per-state rows after them."""

    def steps_of(self, names: Collection[str], start: int, stop: int) -> StepBlock:
        """`steps(start, stop)` of the fields `names` only: a format that reads a field without the others (HDF5)
        leaves the rest unread (camera frames, for a window of states)."""
        block = self.steps(start, stop)
        return StepBlock.of({n: block[n] for n in names})

    def blocks(self, rows: int | None = None) -> Iterator[tuple[int, StepBlock]]:
        """(first step, block) for every block of `rows` steps (None: `block_rows`), in order."""
        rows = rows or block_rows(self.fields)
        for start in range(0, self.length, rows):
            yield start, self.steps(start, min(self.length, start + rows))

    def read_through(self) -> None:
        """Read every row, a block at a time, keeping none: for the checks reading makes (checksums, row counts)."""
        self.reset()
        for _ in self.blocks():
            pass

    def episode(self, rows: int | None = None, *, obs: bool = True) -> Episode:
        """The whole episode, put together from its blocks (`join_blocks`); `obs=False` leaves the observations out,
        reading them a block at a time (camera frames of a long episode never sit in memory whole)."""
        if obs:
            fields, rows = self.fields, rows or self.length or None
        else:
            fields = [f for f in self.fields if not f.name.startswith("obs/")]
        names = [f.name for f in fields]
        steps = [StepBlock.of({n: block[n] for n in names}) for _, block in self.blocks(rows)]
        reset = self.reset()
        reset = StepBlock.of({n: reset[n] for n in names if n in reset.arrays})
        return Episode.from_fields(self.meta, join_blocks(fields, reset, steps))

    @staticmethod
    def of(episode: Episode) -> EpisodeRows:
        """An episode already in memory, read like one in a file (a shipped episode, an explanation's replays)."""
        return _MemoryRows(episode)


class PassedRows(EpisodeRows):
    """Another episode's rows (under other metadata or fields, when given), each block handed to `passed` and the
    reset row to `passed_reset` as it is read: what a copy changes or checks on the way. It walks the inner rows'
    own `blocks()` (an MCAP episode is read front to back once)."""

    def __init__(self, rows: EpisodeRows, meta: EpisodeMeta | None = None,
                 fields: Sequence[FieldSpec] | None = None) -> None:
        super().__init__(meta or rows.meta, rows.fields if fields is None else fields)
        self._rows = rows

    def reset(self) -> StepBlock:
        return self.passed_reset(self._rows.reset())

    def steps(self, start: int, stop: int) -> StepBlock:
        return self.passed(start, self._rows.steps(start, stop))

    def blocks(self, rows: int | None = None) -> Iterator[tuple[int, StepBlock]]:
        for start, block in self._rows.blocks(rows):
            yield start, self.passed(start, block)

    def passed_reset(self, block: StepBlock) -> StepBlock:
        return block

    def passed(self, start: int, block: StepBlock) -> StepBlock:
        """The block of steps from `start` as this episode gives it."""
        return block


class _MemoryRows(EpisodeRows):
    def __init__(self, episode: Episode) -> None:
        super().__init__(episode.meta, _fields_of(episode))
        self._episode = episode

    @property
    def length(self) -> int:
        return self._episode.length

    def reset(self) -> StepBlock:
        return self._episode.reset_block()

    def steps(self, start: int, stop: int) -> StepBlock:
        return StepBlock.of({f.name: a[start + f.per_state : stop + f.per_state]
                             for f, a in zip(self.fields, self._episode.fields().values(), strict=True)})


def _fields_of(episode: Episode) -> list[FieldSpec]:
    """The field table of an episode in memory, in the order of `Episode.fields`."""
    per_state = set(episode.reset_block().arrays)
    return [FieldSpec(name, a.dtype.name, tuple(a.shape[1:]), name in per_state) for name, a in episode.fields().items()]


class EpisodeReader(ABC):
    """Reads one recording file: `meta`, the list of `episodes` (metadata only) and each episode's data."""

    path: Path
    meta: RecordingMeta
    episodes: list[EpisodeMeta]
    """The episodes that can be read, by index."""
    unfinished: list[str] = []  # noqa: RUF012 - read-only default, readers set their own
    """Episodes that began but were never committed (the recording process stopped first): lost."""
    damaged: list[str] = []  # noqa: RUF012
    """Episodes the file holds but that cannot be read (corrupt or half written), each with what is wrong."""
    notes: list[str] = []  # noqa: RUF012
    """Anything else a user should know about the file (a side file that lags, a staged replacement left
    by a killed writer)."""
    kind: str = "recording"
    """What the file is, for people: "simreel HDF5 recording (format 1)", "ManiSkill trajectory file", ..."""

    closed = False
    """Set by `close`: nothing more is read (`check_open`)."""

    def check_open(self) -> None:
        """`UsageError` once the reader is closed (`closed_reader`)."""
        if self.closed:
            raise closed_reader(self.path)

    @abstractmethod
    def open_episode(self, index: int) -> EpisodeRows:
        """The episode whose `EpisodeMeta.index` is `index`, to be read in blocks of rows (`check_open` first)."""

    def read_episode(self, index: int) -> Episode:
        """The whole episode whose `EpisodeMeta.index` is `index` (its blocks put together: `EpisodeRows.episode`)."""
        return self.open_episode(index).episode()

    def __len__(self) -> int:
        return len(self.episodes)

    def __iter__(self) -> Iterator[Episode]:
        for m in self.episodes:
            yield self.read_episode(m.index)

    def refuse_damaged(self, doing: str) -> None:
        """`RecordingFileError` naming the damaged episodes, if the file has any: a command `doing` ("replayed",
        "audited along") every episode never leaves one out silently, nor calls the rest all of it."""
        if self.damaged:
            raise RecordingFileError(self.path, f"damaged, cannot be {doing}: {'; '.join(self.damaged)}; name the "
                                                f"others with --episodes; {self.recover_hint()}")

    def recover_hint(self) -> str:
        """What to do with the file when it has damaged episodes: the `simreel recover` command that keeps the intact
        ones."""
        return f"`simreel recover {self.path}` keeps its intact episodes"

    def episode_meta(self, index: int) -> EpisodeMeta:
        """The metadata of episode `index`; `RecordingFileError` naming the episodes there are, and where the file has
        damaged ones (which it cannot list), those too and how to recover it. `UsageError` for an index that is not
        a whole number: "0" would be "no episode 0" of a file that has it, 0.0 and False would be taken for 0."""
        if not is_whole_number(index):
            raise UsageError(f"{self.path}: episode index {index!r}: give an int (`simreel inspect` lists them)")
        for m in self.episodes:
            if m.index == index:
                return m
        have = ", ".join(str(m.index) for m in self.episodes) or "none"
        if self.damaged:
            raise RecordingFileError(self.path, f"no readable episode {index} (readable: {have}); damaged: "
                                                f"{'; '.join(self.damaged)}; {self.recover_hint()}")
        raise RecordingFileError(self.path, f"no episode {index} (episodes: {have})")

    def named_episodes(self, episodes: Iterable[int]) -> list[int]:
        """The indices of `episodes` (an `EpisodeSelection`, or indices), each once, in the order first named (``0,0``
        or ``0-3,2`` name an episode twice: one video, one conversion of it); `episode_meta`'s `RecordingFileError`
        for the first the file lacks. Each is checked as it comes, so a range that runs past the file's episodes is
        refused at the first it lacks, never walked to its end (``--episodes 0-99999999``)."""
        held, named = {m.index for m in self.episodes}, {}
        for index in episodes:
            if index not in held:
                self.episode_meta(index)  # raises, naming the episodes the file has
            named[index] = None
        return list(named)

    def close(self) -> None:  # noqa: B027 - optional hook
        pass

    def __enter__(self) -> EpisodeReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def closed_reader(path: str | Path) -> UsageError:
    """The error for a read through a closed reader, or an episode it opened: the file may be fine (a failed read of a
    closed file would otherwise be taken for a damaged one)."""
    return UsageError(f"{path}: this reader is closed; open_reader the file again")
