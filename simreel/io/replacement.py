"""Files that replace others as one unit: a recording and the files beside it (an HDF5 file and its JSON sidecar),
or every output of one command (`filter --rest`: two recordings), moved into place by several renames.

No file system renames two files at once, so the renames are written down first: a `Replacement` makes, beside
each final name, a small hidden file (``.NAME.replacing``, `intent_path`) listing every rename and removal of the
unit, made whole and locked before it appears, kept for as long as the renames take and deleted once they are
all done. So:

- a second command replacing the same name waits for the first to finish (a few milliseconds) and then makes
  its own whole unit: two runs never leave a mix of their files;
- a command killed between two renames (kill -9, a power cut) leaves the list behind, unlocked: every reader of
  that name refuses it with one line (`interrupted`: its files may be half old, half new, an .h5 with another
  recording's sidecar), every writer too, and `simreel recover NAME` does the renames that are left
  (`finish`), all of them checked files, complete before the first rename began.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from simreel.errors import UsageError
from simreel.io.lock import lock_file
from simreel.io.targets import short_name

__all__ = ["intent_path", "replacing", "interrupted", "refuse_interrupted", "finish", "sync_path", "INTERRUPTED"]

INTERRUPTED = ("a command replacing it was stopped between its renames, so it and the files beside it may be half "
               "old, half new (an .h5 beside another recording's sidecar)")
"""What a name whose replacement was interrupted is, in the one line a command prints for it."""
PAUSE_VARIABLE = "SIMREEL_TEST_PAUSE_BETWEEN_RENAMES"
"""Seconds to wait between two renames of a unit (tests: a window in which to kill or race the command)."""
_WAIT_S = 30.0
"""How long a command waits for another one's replacement of the same name (it takes milliseconds)."""
_POLL_S = 0.01
_held: set[tuple[int, int]] = set()
"""(device, inode) of the lists this process holds: its own replacement is no other's interrupted one."""


def intent_path(final: Path) -> Path:
    """The list of a replacement of `final` in progress: ``.NAME.replacing`` beside it."""
    return final.with_name(f".{short_name(final.name)}.replacing")


@contextmanager
def replacing(finals: Sequence[Path], moves: Sequence[tuple[Path, Path]], removals: Sequence[Path] = ()
              ) -> Iterator[Callable[[Callable[[Path, Path], None]], None]]:
    """Hold the replacement of `finals` (waiting while another command replaces one of them) for the block, which
    gets a function `run(move)`: it calls `move(src, dst)` for each of `moves` in order, then removes `removals`
    (files and folders the new recordings lack). The list of the unit stays beside each final name until the block
    ends; a command killed inside the block leaves it, for `finish`. `UsageError` when one is left there already."""
    document = json.dumps({"moves": [[str(s.absolute()), str(d.absolute())] for s, d in moves],
                           "removals": [str(p.absolute()) for p in removals],
                           "finals": [str(f.absolute()) for f in finals]})
    held: list[tuple[Path, int]] = []
    try:
        for final in sorted({f.absolute() for f in finals}):
            held.append((intent_path(final), _claim(final, document)))
        yield lambda move: _run(moves, removals, move)
    finally:
        for intent, fd in reversed(held):
            intent.unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                st = os.fstat(fd)
                _held.discard((st.st_dev, st.st_ino))
            os.close(fd)


def _run(moves: Sequence[tuple[Path, Path]], removals: Sequence[Path], move: Callable[[Path, Path], None]) -> None:
    pause = float(os.environ.get(PAUSE_VARIABLE) or 0)
    for k, (src, dst) in enumerate(moves):
        if k and pause:
            time.sleep(pause)
        move(src, dst)
    for folder in {dst.parent for _, dst in moves}:
        sync_path(folder)
    for path in removals:
        _remove(path)


def _claim(final: Path, document: str) -> int:
    """The descriptor of a new list at `intent_path(final)`, locked (made whole and locked under another name, then
    linked there: no one sees it half written or unlocked). Waits while another command holds one."""
    intent = intent_path(final)
    deadline = time.monotonic() + _WAIT_S
    while True:
        fd, tmp = tempfile.mkstemp(prefix=f"{intent.name}.", dir=intent.parent)
        try:
            with os.fdopen(os.dup(fd), "wb") as fh:
                lock_file(fh, exclusive=True)  # held by `fd` too: one open file
                fh.write(document.encode())
                fh.flush()
                os.fsync(fh.fileno())
            os.link(tmp, intent)
            st = os.fstat(fd)
            _held.add((st.st_dev, st.st_ino))
            return fd
        except FileExistsError:
            os.close(fd)
        except BaseException:
            os.close(fd)
            raise
        finally:
            os.unlink(tmp)
        if _abandoned(intent, deadline):
            raise UsageError(f"{final}: {INTERRUPTED}; `simreel recover {final}` finishes that replacement")
        if time.monotonic() > deadline:
            raise UsageError(f"{final} is being replaced by another command that has not finished in {_WAIT_S:.0f} s; "
                             "try again when it has")


def _abandoned(intent: Path, deadline: float) -> bool:
    """Whether the list `intent` is one a killed command left (there, and unlocked), after waiting until `deadline`
    while a live command holds it; False when it is gone, this process's own, or still held at the deadline."""
    try:
        fh = open(intent, "rb")
    except OSError:
        return False
    with fh:
        st = os.fstat(fh.fileno())
        if (st.st_dev, st.st_ino) in _held:
            return False
        while not lock_file(fh, exclusive=True):
            if time.monotonic() > deadline:
                return False
            time.sleep(_POLL_S)
        try:
            now = os.stat(intent)
        except OSError:
            return False  # the command finished (it deletes the list, then lets go of it)
        return (now.st_dev, now.st_ino) == (st.st_dev, st.st_ino)


def interrupted(final: str | os.PathLike[str]) -> bool:
    """Whether a replacement of `final` was interrupted between its renames (its list left there, no one holding
    it). One in progress is waited for (milliseconds), as a reader waits for a commit."""
    intent = intent_path(Path(final))
    return intent.exists() and _abandoned(intent, time.monotonic() + _WAIT_S)


def refuse_interrupted(final: str | os.PathLike[str]) -> None:
    """`UsageError` when a replacement of `final` was interrupted (`interrupted`): nothing is written there until
    `simreel recover` has finished it."""
    if interrupted(final):
        raise UsageError(f"{final}: {INTERRUPTED}; `simreel recover {final}` finishes that replacement, before "
                         "anything else is written there")


def finish(final: str | os.PathLike[str]) -> str | None:
    """Do the renames and removals an interrupted replacement of `final` left undone (`interrupted`), for every
    name of its unit; returns what was done, in a line, or None when there was nothing to finish. The files it
    moves were whole and checked before the first rename."""
    intent = intent_path(Path(final))
    if not interrupted(final):
        return None
    unit = json.loads(intent.read_text())
    moves = [(Path(s), Path(d)) for s, d in unit["moves"]]
    finals = [Path(f) for f in unit["finals"]]
    done = sum(1 for s, _ in moves if not s.exists())
    with contextlib.ExitStack() as held:
        for name in finals:
            with contextlib.suppress(OSError):
                fh = held.enter_context(open(intent_path(name), "rb"))
                lock_file(fh, exclusive=True)
        _run([(s, d) for s, d in moves if s.exists()], [Path(p) for p in unit["removals"]], os.replace)
        for name in finals:
            intent_path(name).unlink(missing_ok=True)
    return (f"finished replacing {', '.join(str(f) for f in finals)}: a command was stopped between its renames "
            f"({done} of its {len(moves)} renames were done)")


def sync_path(path: Path) -> None:
    """`os.fsync` the file or folder `path`, so its data or names reach the disk before what depends on them
    changes; nothing where the file system cannot."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
