"""Where the dataset commands write their outputs: under a staging name beside the final one
(`simreel.io.staging.staging_path`), moved there only once complete (`publish_outputs`).

So the final name never holds part of an output: a command killed (even with -9) while it copies leaves the old
file there as it was, or no file at all, and a hidden staging file that the next command writing the same name
removes (`clear_stale`). `convert`, `recover`, `merge`, `filter`, `replay -o` and conversions all publish this way.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simreel.errors import UsageError
from simreel.formats import check_writable, recording_files, remove_recording
from simreel.io.durable import deferred_signals, raise_if_stopped
from simreel.io.replacement import replacing, sync_path
from simreel.io.staging import staging_path, stale_staging
from simreel.io.targets import OVERWRITE_HINT, move_into_place
from simreel.model.meta import RecordingMeta

__all__ = ["Target", "StagedOutput", "publish_outputs", "clear_stale"]


@dataclass(frozen=True)
class Target:
    """A recording a copy writes: where, with what metadata, and whether it may replace a file."""

    path: Path
    meta: RecordingMeta
    overwrite: bool


@dataclass
class StagedOutput:
    """One output while it is made: written under a staging name beside its final one (or, for `replay -o` and
    conversions, in their scratch folder), then moved to its final name complete (`publish_outputs`)."""

    final: Target
    staged: Target
    items: list[Any] = field(default_factory=list)
    """The episodes it receives, in order (merge and filter)."""
    digests: list[bytes] = field(default_factory=list)
    """`episode_digest` of each episode as read from its source (merge and filter check the output against them)."""

    @classmethod
    def of(cls, target: Target) -> StagedOutput:
        return cls(target, dataclasses.replace(target, path=staging_path(target.path), overwrite=True))

    def _pairs(self) -> list[tuple[Path, Path]]:
        """(staged file, final name) of the recording's side files, then of the recording (a reader that finds it
        finds its sidecar)."""
        pairs = list(zip(recording_files(self.staged.path), recording_files(self.final.path), strict=True))
        return pairs[1:] + pairs[:1]

    def check_free(self) -> None:
        """`UsageError` when the staged recording is gone (another command removed it), when, without `overwrite`,
        a final name is taken by now (another command writing the same OUT), or when a recording is being written
        at the final name now; touches nothing, so a command checks every output before it publishes any."""
        if not self.staged.path.is_file():
            raise UsageError(f"{self.final.path}: its output, written as {self.staged.path.name}, was removed by "
                             "another command while this one ran; nothing was written")
        for src, dst in self._pairs():
            if not self.final.overwrite and src.exists() and (dst.exists() or dst.is_symlink()):
                raise self._taken(dst)
        check_writable(self.final.path, overwrite=self.final.overwrite)

    def moves(self) -> list[tuple[Path, Path]]:
        """(staged file, final name) of each file of the staged recording: its side files first, the recording last."""
        return [(src, dst) for src, dst in self._pairs() if src.exists()]

    def removals(self) -> list[Path]:
        """Files of an old recording at the final name that the new one lacks (its `.partial/` folder, which may hold
        the journal of a killed recording's lost episodes): removed once the new one is in place, with `overwrite`
        only, as the output rule checked at the start."""
        return [dst for src, dst in self._pairs() if not src.exists()] if self.final.overwrite else []

    def move(self, src: Path, dst: Path) -> None:
        """Move one staged file to its final name; a name taken since the start (a file made after `check_free`)
        is never replaced without `overwrite`."""
        try:
            move_into_place(src, dst, overwrite=self.final.overwrite)
        except FileExistsError:
            raise self._taken(dst) from None

    def _taken(self, dst: Path) -> UsageError:
        return UsageError(f"{self.final.path} was written by another command while this one ran ({dst.name} is there "
                          f"now); it is left as it is and nothing was written ({OVERWRITE_HINT})")


def publish_outputs(outputs: Sequence[StagedOutput]) -> None:
    """Publish every output or none, as one unit (`simreel.io.replacement`): each recording's files and every
    output's are replaced together, another command replacing the same names waits, a kill between two renames
    leaves a list that readers refuse and `simreel recover` finishes. Each output is checked (`check_free`) before
    any is moved, each staged recording made durable first, and SIGINT and SIGTERM are held until every file is
    moved."""
    raise_if_stopped()  # a Ctrl-C that landed in a finalizer (h5py's) was printed and dropped by Python
    by_name = {dst: output for output in outputs for _, dst in output.moves()}
    moves = [pair for output in outputs for pair in output.moves()]
    with replacing([o.final.path for o in outputs], moves, [p for o in outputs for p in o.removals()]) as run:
        for output in outputs:
            output.check_free()
            sync_path(output.staged.path)
        with deferred_signals():
            run(lambda src, dst: by_name[dst].move(src, dst))
    for output in outputs:
        remove_recording(output.staged.path)  # what is left of it: the side folder its writer used


def clear_stale(final: Path) -> list[Path]:
    """Remove what killed commands left beside the published `final` (`stale_staging`), with its files beside it."""
    stale = stale_staging(final)
    for path in stale:
        remove_recording(path)
    return stale
