"""Copy recordings episode by episode: `convert` between formats (losslessly, or not at all) and `recover` what
can be read of a recording whose process was killed or whose file is damaged.

Both write a new file through `open_writer`, check their output with the one output rule first
(`simreel.io.targets`), write it under a staging name beside its final one and move it there only once it is
complete (`simreel.datasets.staged`): a copy that fails or is killed leaves no part of it at the output's name, and
an output it was to replace stays as it was.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TypeVar

from simreel.datasets.staged import StagedOutput, Target, clear_stale, publish_outputs
from simreel.errors import RecordingFileError, StorageError, UsageError
from simreel.formats import (
    check_writable,
    format_of,
    open_reader,
    open_writer,
    recording_files,
    remove_recording,
)
from simreel.formats.base import EpisodeReader, EpisodeRows, EpisodeWriter
from simreel.io.durable import raise_if_stopped
from simreel.io.paths import real_path, refuse_empty
from simreel.io.replacement import finish as finish_replacement
from simreel.io.staging import replacement_note
from simreel.io.targets import check_distinct
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.options.checks import check_flag, path_text

__all__ = ["EpisodeTransform", "CopyReport", "RecoveryReport", "convert", "recover"]

_T = TypeVar("_T")


class EpisodeTransform(Protocol):
    """Changes every episode on its way to the output (e.g. adds body poses computed in a rebuilt env): it takes
    an episode's rows as opened and returns the rows to write, changed as they are read, a block at a time."""

    meta: RecordingMeta
    """The output recording's metadata."""

    def __call__(self, rows: EpisodeRows) -> EpisodeRows: ...

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
    notes: list[str] = field(default_factory=list)
    """What the input's reader says of it as a whole (`EpisodeReader.notes`: groups of a ManiSkill file its sidecar
    does not list, which are not copied either)."""


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
    through (``simreel convert --poses``). `progress` wraps the episode list (a progress bar). A damaged
    episode makes the whole copy fail (naming it): `recover` copies the intact ones.
    """
    format_of(dst)  # a bad suffix, or none (Path("") is "."), fails before anything is read
    src_p, dst_p = Path(src), Path(dst)
    check_distinct({"OUT": recording_files(dst_p)}, recording_files(src_p), input_label="IN")
    check_writable(dst_p, overwrite=overwrite)  # before the reader and a transform's env cost anything
    with open_reader(src_p) as reader:
        if reader.damaged:
            raise RecordingFileError(src_p, f"{len(reader.damaged)} damaged episode(s) ({'; '.join(reader.damaged)}); "
                                            f"`simreel recover {src} -o {dst}` copies the intact ones")
        change = transform(reader.meta) if transform is not None else None
        try:
            meta = change.meta if change is not None else reader.meta
            copied = _copy(reader, progress(reader.episodes), Target(dst_p, meta, overwrite), change)
        finally:
            if change is not None:
                change.close()
        return CopyReport(len(reader.episodes), copied.steps, meta, list(reader.unfinished), list(reader.notes))


def write_episodes(targets: Sequence[Target], episodes: Iterable[tuple[int, EpisodeRows]]) -> list[int]:
    """Write each (target number, episode) of `episodes` to `targets[number]`, all of them new recordings; returns
    the steps written to each. Each episode is copied a block of rows at a time. Every target is created before
    the first episode is read; any failure (Ctrl-C included) drops every target (`EpisodeWriter.abort`: a
    recording a target was to replace stays as it was).

    A writer that refuses its target (it exists, another recording writes it) has created nothing, and what is
    there is not this call's to delete; the targets created before it are dropped."""
    writers: list[EpisodeWriter] = []
    try:
        for target in targets:
            writers.append(open_writer(target.path, target.meta, overwrite=target.overwrite))
        steps = [0] * len(targets)
        for k, episode in episodes:
            raise_if_stopped()  # a Ctrl-C that landed in a finalizer (h5py's) was printed and dropped by Python
            writers[k].write_rows(episode)
            steps[k] += episode.length
        raise_if_stopped()
        for writer in writers:
            writer.close()
    except BaseException:
        for writer in writers:
            writer.abort()
        raise
    return steps


@dataclass
class _Copied:
    episodes: int = 0
    steps: int = 0
    lost: list[str] = field(default_factory=list)
    """Episodes that could not be read (`salvage` only), each with why."""


def _copy(reader: EpisodeReader, episodes: Iterable[EpisodeMeta], target: Target,
          change: EpisodeTransform | None = None, *, salvage: bool = False) -> _Copied:
    """Write `episodes` of `reader` (through `change`, when given) to a new recording `target`: under a staging name
    beside it, moved there once complete (`simreel.datasets.staged`), so `target` never holds part of a copy, even
    after a kill -9. A failure drops the new recording (an output it was to replace stays); with `salvage`, an episode that cannot be read is named in
    `lost` and the copy goes on.

    An episode is copied a block of rows at a time (memory bounded whatever its length); `salvage` reads each one
    through first, a block at a time too, so that a damaged episode is found before any of it is written."""
    copied = _Copied()

    def read() -> Iterator[tuple[int, EpisodeRows]]:
        for m in episodes:
            try:
                if salvage:
                    reader.open_episode(m.index).read_through()
                episode = reader.open_episode(m.index)
                if change is not None:
                    episode = change(episode)
            except RecordingFileError as e:
                if not salvage:
                    raise
                copied.lost.append(f"episode {m.index} ({e.problem})")
                continue
            copied.episodes += 1
            yield 0, episode

    output = StagedOutput.of(target)
    try:
        copied.steps = write_episodes([output.staged], read())[0]
        publish_outputs([output])
    except BaseException as e:
        remove_recording(output.staged.path)
        if isinstance(e, StorageError):
            raise _nothing_written(e, target, reader) from None
        raise
    clear_stale(target.path)
    return copied


def _nothing_written(e: StorageError, target: Target, reader: EpisodeReader) -> StorageError:
    """A copy's storage failure: it wrote nothing (a failed copy is dropped) and its input is as it was."""
    return e.dropped(f"; nothing was written and {reader.path} is unchanged", target.path)


@dataclass
class RecoveryReport:
    """What `recover` found and did."""

    complete: bool
    """The file was complete (nothing unfinished, damaged or lagging): nothing to recover."""
    episodes: int
    steps: int
    unfinished: list[str]
    """Episodes that had begun but were never committed: lost."""
    lost_bytes: int
    """Bytes at the end of the file that do not form a whole record (cut mid-write): lost."""
    output: str | None = None
    """The recovered file (None when nothing was written)."""
    damaged: list[str] = field(default_factory=list)
    """Committed episodes (or records, or stretches of bytes) found damaged and not copied: lost."""
    notes: list[str] = field(default_factory=list)
    """What else the reader noticed (a sidecar that lagged, a staged replacement left behind)."""
    live: bool = False
    """A recording was still writing the file: its running episodes were not copied, and not lost either."""
    finished: str | None = None
    """A replacement of the file that a killed command left half done, finished first (`simreel.io.replacement`)."""


def _open_for_recovery(src: Path) -> EpisodeReader:
    if format_of(src) == "mcap":
        from simreel.formats.mcap.reader import McapReader

        return McapReader(src, recover=True)
    return open_reader(src)


def _is_maniskill_file(reader: EpisodeReader) -> bool:
    """Whether `reader` reads a ManiSkill trajectory file (not a simreel recording made from one)."""
    from simreel.formats.maniskill.reader import ManiskillReader

    return isinstance(reader, ManiskillReader)


def _all_intact(reader: EpisodeReader) -> bool:
    """Whether every episode's data reads back whole (checksums, layout): damage in a chunk shows only when it is
    read, so a file complete in its structure is read through before `recover` calls it complete."""
    for m in reader.episodes:
        try:
            reader.open_episode(m.index).read_through()
        except RecordingFileError:
            return False
    return True


def recover(path: str | Path, output: str | Path | None = None, *, overwrite: bool = False) -> RecoveryReport:
    """Rewrite every intact committed episode of the recording `path` into `output` (default: `path` itself, which
    is replaced only once the new file is complete) and report what was lost: episodes that never finished,
    damaged ones, damaged records and bytes. A recording with nothing to repair (read through: every episode's data
    intact) is left as it is. A replacement of `path` that a command killed between its renames left half done is
    finished first (`RecoveryReport.finished`)."""
    path = path_text("path", path, "the recording to recover, a str or pathlib.Path")
    refuse_empty(path, what="recording", instead="name the recording to recover")
    if output is not None:
        output = path_text("output", output, "the file to write, a str or pathlib.Path, or None (replace `path`)")
        refuse_empty(output, what="recording", instead="name the file to write, or give None to recover in place")
    check_flag("overwrite", overwrite)
    src = Path(path)
    format_of(src)
    in_place = output is None or real_path(output) == real_path(src)
    note = replacement_note(src)
    if in_place and note is not None:
        raise UsageError(f"{src}: {note}; recover that one with -o, or remove it, before recovering {src} in place")
    if not in_place:
        format_of(output)
        check_distinct({"-o": recording_files(output)}, recording_files(src), input_label="the recording to recover")
        check_writable(output, overwrite=overwrite)  # refuse OUT before reading PATH front to back
    finished = finish_replacement(src)  # a kill between two renames: the renames left, done first
    with _open_for_recovery(src) as reader:
        damaged = [*reader.damaged, *getattr(reader, "skipped", [])]
        report = RecoveryReport(
            complete=not (getattr(reader, "recovered", False) or reader.unfinished or damaged or reader.notes)
            and (output is not None or _all_intact(reader)),
            episodes=0, steps=0, unfinished=list(reader.unfinished), lost_bytes=getattr(reader, "lost_bytes", 0),
            damaged=damaged, notes=list(reader.notes), live=bool(getattr(reader, "live", False)), finished=finished,
        )
        if report.complete and output is None:
            report.episodes, report.steps = len(reader.episodes), sum(e.length for e in reader.episodes)
            return report
        if in_place and _is_maniskill_file(reader):
            raise UsageError(f"{src} is a ManiSkill file (RecordEpisode's): recovering it in place would replace it "
                             "by a simreel recording, losing its sidecar's own fields and any group the sidecar does not "
                             "list; recover it with -o")
        dst = src if in_place else Path(output)
        copied = _copy(reader, reader.episodes, Target(dst, reader.meta, overwrite or in_place), salvage=True)
    report.episodes, report.steps = copied.episodes, copied.steps
    report.damaged += copied.lost
    report.output = str(dst)
    return report
