"""Copy recordings episode by episode: `convert` between formats (losslessly) and `recover` the committed
episodes of an MCAP recording whose process was killed.

Both write a new file through `open_writer`, check their output with the one output rule first
(`simreel.formats.targets`), and leave no half-written output behind when they fail.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TypeVar

from simreel.episode import Episode, EpisodeMeta, RecordingMeta
from simreel.errors import UsageError
from simreel.formats import check_writable, format_of, open_reader, open_writer, remove_recording
from simreel.formats.base import EpisodeReader

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
            steps = _copy(reader, progress(reader.episodes), _Target(dst_p, meta, overwrite), change)
        finally:
            if change is not None:
                change.close()
        return CopyReport(len(reader.episodes), steps, meta, list(getattr(reader, "unfinished", [])))


@dataclass(frozen=True)
class _Target:
    """The recording a copy writes: where, with what metadata, and whether it may replace a file."""

    path: Path
    meta: RecordingMeta
    overwrite: bool


def _copy(reader: EpisodeReader, episodes: Iterable[EpisodeMeta], target: _Target,
          change: EpisodeTransform | None = None) -> int:
    """Write `episodes` of `reader` to a new recording `target`; returns the steps copied. A failure removes it.

    The writer is built outside the try: a writer that refuses the target (it exists, another recording writes
    it) has created nothing, and what is there is not this call's to delete."""
    steps = 0
    dst = target.path
    writer = open_writer(dst, target.meta, overwrite=target.overwrite)
    try:
        with writer:
            for m in episodes:
                episode = reader.read_episode(m.index)
                writer.write_episode(change(episode) if change is not None else episode)
                steps += episode.length
    except BaseException:
        remove_recording(dst)
        raise
    return steps


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
        _copy(reader, reader.episodes, _Target(dst, reader.meta, overwrite or in_place))
    if in_place:
        os.replace(dst, src)
        dst = src
    report.output = str(dst)
    return report
