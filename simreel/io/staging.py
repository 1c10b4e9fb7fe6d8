"""Where a writer puts a recording, so that `--overwrite` never removes the old one before the new one is complete.

A new recording is written under its own name from the start: every episode it commits is readable there at
once, while it is being written, and after its process is killed. A recording that replaces an existing one
is *staged*: written in the side folder beside it (``NAME.partial/NAME``, files beside it there too) and moved
over the old one, with one rename per file, when the writer closes. Until then the old recording stays whole
and readable; if the process dies first the old one is untouched and the staged one keeps its committed
episodes (readers say where).

Either way the writer holds a `WriterLock` on the name (the old file, or the new one), so a second writer of
the same name is refused with one line, and on the file it writes.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from simreel.errors import UsageError
from simreel.io.lock import WriterLock, being_written
from simreel.io.replacement import refuse_interrupted, replacing
from simreel.io.targets import check_output, made_by_gone_process, process_alive, process_tag, short_name

__all__ = ["RecordingTarget", "side_folder", "replacement_note", "refuse_kept_recording", "staging_path",
           "is_staging_path", "stale_staging"]


def side_folder(path: Path) -> Path:
    """The folder beside a recording for what its writer keeps apart (`x.h5` → `x.h5.partial`)."""
    return path.with_name(path.name + ".partial")


def replacement_note(path: Path) -> str | None:
    """What a reader of `path` should know about a recording staged to replace it: one being written now, or one
    whose writer died before it was complete (its committed episodes are there). None when there is none."""
    staged = side_folder(path) / path.name
    if not staged.is_file():
        return None
    if being_written(staged):
        return f"a recording that will replace this one when it is complete is being written in {staged}"
    return (f"a recording that was to replace this one stopped before it was complete; its committed episodes are "
            f"in {staged} (this file is unchanged)")


def refuse_kept_recording(path: Path) -> None:
    """`UsageError` when the side folder of `path` holds a staged recording a writer left there (one that stopped
    before it was complete, or was killed): it holds committed episodes, which no `--overwrite` of `path` removes."""
    folder = side_folder(path)
    staged = folder / path.name
    if staged.is_file() and not folder.is_symlink() and not being_written(staged):
        raise UsageError(f"{staged} holds the episodes of a recording that stopped before it was complete; move it "
                         f"out of {folder} (or delete that folder) first: --overwrite replaces {path}, never that "
                         "recording")


@dataclass
class RecordingTarget:
    """The file a writer writes (`write_path`) for the recording `path`, and the locks it holds."""

    path: Path
    write_path: Path
    folder: Path
    """The side folder (`side_folder(path)`); the writer creates it when it needs it."""
    locks: list[WriterLock] = field(default_factory=list)
    created: bool = False
    """This writer created `path` (a new recording), so dropping its recording removes it."""

    @property
    def staged(self) -> bool:
        """True when the recording replaces an existing one, so it is written in the side folder until `publish`."""
        return self.write_path != self.path

    def beside(self, name: str) -> Path:
        """Where the side file `name` (e.g. HDF5's JSON sidecar) is written until `publish`."""
        return (self.folder if self.staged else self.path.parent) / name

    @classmethod
    def claim(cls, path: Path, side_paths: list[Path], *, overwrite: bool) -> RecordingTarget:
        """Check the target (`check_output`), lock it and decide where to write. Without `overwrite` an existing
        file or side file is refused; with it, a file another writer holds is still refused. Leftovers of an
        earlier writer in the side folder (never-committed scratch files, a staged file it did not finish) are
        removed once the name is locked; a staged recording one left there (stopped before it was complete, or
        killed: its committed episodes are in it) is never removed, `overwrite` or not: `UsageError` saying so."""
        check_output(path, overwrite=overwrite, side_paths=side_paths)
        refuse_interrupted(path)
        existing = overwrite and (path.exists() or path.is_symlink())
        target = cls(path, path, side_folder(path), [WriterLock.acquire(path, create=not existing)], not existing)
        try:
            refuse_kept_recording(path)
            target._clear_folder()  # the name is ours now: what is there was left by a writer that has ended
            if existing:
                target.folder.mkdir()
                target.write_path = target.folder / path.name
                target.locks.append(WriterLock.acquire(target.write_path, create=True))
        except OSError as e:
            target.abandon()
            raise UsageError(f"cannot write {target.folder}: {e.strerror or e}") from None
        except BaseException:
            target.abandon()
            raise
        return target

    def _clear_folder(self) -> None:
        if self.folder.is_dir() and not self.folder.is_symlink():
            shutil.rmtree(self.folder)
        elif self.folder.exists() or self.folder.is_symlink():
            self.folder.unlink()

    def publish(self, side_files: list[str] = (), *, replace: bool = True) -> None:
        """Move a staged recording (and its `side_files`, by name) over the old one; then give up the locks.
        `replace=False` (a recording stopped before it was complete) leaves a staged one in the side folder, where
        readers of the old one are told about it (`replacement_note`), and the old one as it is.

        The side files go first and the recording last (a reader that finds the new recording finds its sidecar),
        with SIGINT and SIGTERM held until all are moved (a signal between two moves left the new recording beside
        the old one's sidecar, which ManiSkill's loader reads: other seeds, other episodes), as one unit
        (`simreel.io.replacement`: a kill -9 between two moves leaves a list that readers refuse and `simreel
        recover` finishes)."""
        from simreel.io.durable import deferred_signals

        if self.staged and not replace:
            self.release()
            return
        try:
            if self.staged:
                moves = [(self.folder / n, self.path.parent / n) for n in side_files if (self.folder / n).exists()]
                with replacing([self.path], [*moves, (self.write_path, self.path)]) as run, deferred_signals():
                    run(os.replace)
            self.remove_folder_if_empty()
        finally:
            self.release()

    def abandon(self, side_files: list[str] = ()) -> None:
        """Drop what this writer wrote: a staged recording (the old one stays) or a new file with its `side_files`,
        and the side folder when it holds nothing else; then give up the locks."""
        try:
            if self.created and not self.staged:
                for name in side_files:
                    self.beside(name).unlink(missing_ok=True)
            if self.staged:
                shutil.rmtree(self.folder, ignore_errors=True)
            elif self.created:
                self.path.unlink(missing_ok=True)
            self.remove_folder_if_empty()
        finally:
            self.release()

    def remove_folder_if_empty(self) -> None:
        try:
            self.folder.rmdir()
        except OSError:
            pass  # missing, or it holds what a reader should see (scratch of unfinished episodes)

    def release(self) -> None:
        for lock in self.locks:
            lock.release()
        self.locks = []


_STAGING_STEM = re.compile(r"\.(?P<stem>.+)\.simreel-(?P<tag>[0-9]+(@.+)?)")
"""The stem of a staging name (`staging_path`): ``.OUT-STEM.simreel-PID@HOST`` (``.OUT-STEM.simreel-PID`` before
simreel named the machine too)."""


def staging_path(final: Path) -> Path:
    """The name an output of merge or filter is written under beside `final` (``.merged.simreel-PID@HOST.h5`` for
    ``merged.h5``, `process_tag`) until it is checked and moved there: hidden, and this process's own, so that two
    commands writing one OUT never share it, on this machine or another. A long stem is cut as temporary files' are
    (`short_name`), so that a name the file system takes for OUT gives a staging name it takes too."""
    return final.with_name(f".{short_name(final.stem)}.simreel-{process_tag()}{final.suffix}")


def stale_staging(final: Path) -> list[Path]:
    """What commands killed before they moved their output to `final` left beside it under a staging name
    (`staging_path`): unchecked copies of their inputs, never a recording of its own. Not those a writer holds or
    whose process lives (a command checking its output holds no writer lock), nor those of another machine (its
    run may go on: a shared folder), nor any of this process."""
    found = []
    for path in sorted(final.parent.glob(f".*.simreel-*{final.suffix}")):
        match = _STAGING_STEM.fullmatch(path.stem)
        if (match and match["stem"] == short_name(final.stem) and path.is_file() and _left_behind(match["tag"])
                and not being_written(path)):
            found.append(path)
    return found


def _left_behind(tag: str) -> bool:
    """Whether the process a staging name names is gone (`made_by_gone_process`); a name of an earlier simreel, which
    named no machine, is judged by its PID alone, as it was then."""
    return made_by_gone_process(tag) or (tag.isdigit() and not process_alive(int(tag)))


def is_staging_path(path: str | os.PathLike[str]) -> bool:
    """Whether `path` has a staging name (`staging_path`): an output being made, or one a killed merge or filter
    left behind, never a finished recording (folder scans skip it: `simreel.datasets.inputs`)."""
    return _STAGING_STEM.fullmatch(Path(path).stem) is not None
