"""Copy recordings episode by episode: `convert` between formats (losslessly) and `recover` the committed
episodes of an MCAP recording whose process was killed.

Both write a new file through `open_writer`, check their output with the one output rule first
(`simreel.formats.targets`), and leave no half-written output behind when they fail.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from contextlib import ExitStack, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TypeVar

from simreel.episode import Episode, EpisodeMeta, RecordingMeta
from simreel.errors import UsageError
from simreel.formats import check_writable, format_of, open_reader, open_writer, remove_recording
from simreel.formats.base import EpisodeReader, EpisodeWriter

__all__ = ["EpisodeTransform", "CopyReport", "RecoveryReport", "convert", "recover"]

_T = TypeVar("_T")


class EpisodeTransform(Protocol):
    """Changes every episode on its way to the output (e.g. adds body poses computed in a rebuilt env)."""

    meta: RecordingMeta
    """The output recording's metadata."""

    def __call__(self, episode: Episode) -> Episode: ...

    def close(self) -> None: ...


@dataclass
class CopyReport:
    """What `convert` copied."""

    episodes: int
    steps: int
    meta: RecordingMeta
    """The output's metadata."""
    skipped: list[str] = field(default_factory=list)
    """Episodes of the input that were never committed (a killed recording), hence not copied."""


def _no_bar(items: Iterable[_T]) -> Iterable[_T]:
    return items


def convert(
    src: str | Path,
    dst: str | Path,
    *,
    overwrite: bool = False,
    transform: Callable[[RecordingMeta], EpisodeTransform] | None = None,
    progress: Callable[[Iterable[EpisodeMeta]], Iterable[EpisodeMeta]] = _no_bar,
) -> CopyReport:
    """Copy every committed episode of `src` into a new file `dst` (its suffix picks the format).

    `transform(meta)`, when given, builds an `EpisodeTransform` for `src`'s metadata that every episode goes
    through (``simreel convert --poses``). `progress` wraps the episode list (a progress bar).
    """
    src_p, dst_p = Path(src), Path(dst)
    format_of(dst_p)  # a bad suffix fails before anything is read
    if src_p.exists() and dst_p.exists() and src_p.resolve() == dst_p.resolve():
        raise UsageError(f"{dst}: IN and OUT are the same file; write to another file")
    check_writable(dst_p, overwrite=overwrite)  # before the reader and a transform's env cost anything
    with open_reader(src_p) as reader:
        change = transform(reader.meta) if transform is not None else None
        try:
            meta = change.meta if change is not None else reader.meta
            steps = _copy(reader, progress(reader.episodes), Target(dst_p, meta, overwrite), change)
        finally:
            if change is not None:
                change.close()
        return CopyReport(len(reader.episodes), steps, meta, list(getattr(reader, "unfinished", [])))


@dataclass(frozen=True)
class Target:
    """A recording a copy writes: where, with what metadata, and whether it may replace a file."""

    path: Path
    meta: RecordingMeta
    overwrite: bool


def write_episodes(targets: Sequence[Target], episodes: Iterable[tuple[int, Episode]]) -> list[int]:
    """Write each (target number, episode) of `episodes` to `targets[number]`, all of them new recordings; returns
    the steps written to each. Every target is created before the first episode is read; any failure (Ctrl-C
    included) removes every target.

    A writer that refuses its target (it exists, another recording writes it) has created nothing, and what is
    there is not this call's to delete; the targets created before it are."""
    writers: list[EpisodeWriter] = []
    try:
        for target in targets:
            writers.append(open_writer(target.path, target.meta, overwrite=target.overwrite))
    except BaseException:
        _remove_all(writers, [w.path for w in writers])
        raise
    steps = [0] * len(targets)
    try:
        with ExitStack() as stack:
            for writer in writers:
                stack.enter_context(writer)
            for k, episode in episodes:
                writers[k].write_episode(episode)
                steps[k] += episode.length
    except BaseException:
        _remove_all([], [t.path for t in targets])
        raise
    return steps


def _remove_all(open_writers: list[EpisodeWriter], paths: list[Path]) -> None:
    """Close `open_writers` (errors ignored: the files go anyway) and remove the recordings `paths`."""
    for writer in open_writers:
        with suppress(Exception):
            writer.close()
    for path in paths:
        remove_recording(path)


def _copy(reader: EpisodeReader, episodes: Iterable[EpisodeMeta], target: Target,
          change: EpisodeTransform | None = None) -> int:
    """Write `episodes` of `reader` (through `change`, when given) to a new recording `target`; returns the steps
    copied. A failure removes it."""
    read = (reader.read_episode(m.index) for m in episodes)
    return write_episodes([target], ((0, change(e) if change is not None else e) for e in read))[0]


@dataclass
class RecoveryReport:
    """What `recover` found and did."""

    complete: bool
    """The file was complete (a footer, nothing unfinished): nothing to recover."""
    episodes: int
    steps: int
    unfinished: list[str]
    """Episodes that had begun but were never committed: lost."""
    lost_bytes: int
    """Bytes at the end of the file that do not form a whole record (cut mid-write): lost."""
    output: str | None = None
    """The recovered file (None when nothing was written)."""


def _recovering_path(src: Path) -> Path:
    return src.with_name(src.stem + ".recovering.mcap")


def recover(path: str | Path, output: str | Path | None = None, *, overwrite: bool = False) -> RecoveryReport:
    """Rewrite the committed episodes of the MCAP recording `path` into `output` (default: `path` itself,
    atomically through a temporary file beside it) and report what was lost."""
    from simreel.formats.mcap.reader import McapReader

    src = Path(path)
    if format_of(src) != "mcap":
        raise UsageError(f"{src}: only MCAP recordings need recovery; an HDF5 recording keeps its committed "
                         "episodes readable (inspect lists the unfinished ones)")
    in_place = output is None or Path(output).resolve() == src.resolve()
    if not in_place:
        format_of(output)
        check_writable(output, overwrite=overwrite)  # refuse OUT before reading PATH front to back
    with McapReader(src, recover=True) as reader:
        report = RecoveryReport(
            complete=not reader.recovered and not reader.unfinished,
            episodes=len(reader.episodes),
            steps=sum(e.length for e in reader.episodes),
            unfinished=list(reader.unfinished),
            lost_bytes=reader.lost_bytes,
        )
        if report.complete and output is None:
            return report
        dst = _recovering_path(src) if in_place else Path(output)
        _copy(reader, reader.episodes, Target(dst, reader.meta, overwrite or in_place))
    if in_place:
        os.replace(dst, src)
        dst = src
    report.output = str(dst)
    return report
