"""The advisory locks that keep writers and readers of a recording apart, in any process.

- A writer holds an exclusive lock on its recording for its whole life (`WriterLock`), so a second writer is
  refused, and a reader can tell a file that is still being written from one whose recording process died
  (the kernel drops the locks of a dead process): `being_written`.
- An HDF5 writer also holds `CommitLock` exclusively while it changes the file (one commit, a few
  milliseconds); a reader of a file being written takes it shared while it reads the file's structure, so it
  never sees a commit half done.

Locks are `flock` locks: they belong to an open file, not to a process, so h5py opening and closing its own
handle of the same file in the same process never drops them. Where `flock` is unavailable (not POSIX, some
network file systems) every lock is granted: the data is still written the same way, only concurrent use is
unguarded.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from simreel.errors import RecordingFileError, UsageError
from simreel.io.targets import OVERWRITE_HINT

__all__ = ["lock_file", "being_written", "WriterLock", "CommitLock"]

_POLL_S = 0.005
_READ_WAIT_S = 10.0
"""How long a reader waits for a commit in progress before it gives up (a commit takes milliseconds)."""


def _flock(fd: int, operation: str) -> bool:
    """`flock(fd)` with LOCK_EX / LOCK_SH (without waiting) or LOCK_UN; False if another open file holds it."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return True
    flags = {"exclusive": fcntl.LOCK_EX | fcntl.LOCK_NB, "shared": fcntl.LOCK_SH | fcntl.LOCK_NB,
             "wait_exclusive": fcntl.LOCK_EX, "unlock": fcntl.LOCK_UN}[operation]
    try:
        fcntl.flock(fd, flags)
    except BlockingIOError:
        return False
    except OSError:  # pragma: no cover - file systems without flock
        return True
    return True


def lock_file(fh: IO[bytes], *, exclusive: bool) -> bool:
    """Take an advisory lock without waiting; False if another open file holds it (True where unsupported).

    A shared lock is only a probe: it is released at once.
    """
    if not _flock(fh.fileno(), "exclusive" if exclusive else "shared"):
        return False
    if not exclusive:
        _flock(fh.fileno(), "unlock")
    return True


def being_written(path: str | Path) -> bool:
    """True while a writer (in any process) holds `path`'s `WriterLock`."""
    try:
        with open(path, "rb") as fh:
            return not lock_file(fh, exclusive=False)
    except OSError:
        return False


class WriterLock:
    """An exclusive lock on a recording file for as long as a writer writes it. `acquire` refuses with one line
    when another writer holds it; `release` (or the end of the process) gives it up."""

    def __init__(self, fd: int, path: Path) -> None:
        self.fd = fd
        self.path = path

    @classmethod
    def acquire(cls, path: Path, *, create: bool) -> WriterLock:
        """Lock `path`: a new empty file (`create`: refused if it exists) or an existing one (kept as it is)."""
        flags = os.O_RDWR | getattr(os, "O_BINARY", 0) | (os.O_CREAT | os.O_EXCL if create else 0)
        try:
            fd = os.open(path, flags, 0o666)
        except FileExistsError:
            raise UsageError(f"{path} already exists; {OVERWRITE_HINT}") from None
        except OSError as e:
            raise UsageError(f"cannot write {path}: {e.strerror or e}") from None
        if not _flock(fd, "exclusive"):
            os.close(fd)
            raise UsageError(f"{path} is being written by another recording; choose another file, or wait until "
                             "that recording has finished")
        return cls(fd, path)

    def release(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)  # closing the file drops its lock
            self.fd = -1


class CommitLock:
    """The lock an HDF5 writer holds while it changes the file, on the folder beside it (`NAME.h5.partial`),
    which exists exactly while a writer writes."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._fd = os.open(folder, os.O_RDONLY)

    @contextmanager
    def held(self) -> Iterator[None]:
        """Hold the lock exclusively (the writer, around one change of the file); waits for readers that are
        reading the file's structure, which takes them milliseconds."""
        _flock(self._fd, "wait_exclusive")
        try:
            yield
        finally:
            _flock(self._fd, "unlock")

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    @staticmethod
    @contextmanager
    def reading(folder: Path, path: Path) -> Iterator[None]:
        """Hold the lock shared while reading the structure of `path`, whose writer commits under `folder`'s lock
        (nothing to wait for when the folder is gone: its writer has finished). Never waits forever: after
        `_READ_WAIT_S` it raises `RecordingFileError`."""
        try:
            fd = os.open(folder, os.O_RDONLY)
        except OSError:
            yield
            return
        try:
            deadline = time.monotonic() + _READ_WAIT_S
            while not _flock(fd, "shared"):
                if time.monotonic() > deadline:
                    raise RecordingFileError(path, f"being written, and a commit has held it for {_READ_WAIT_S:g} s; "
                                                   "try again (is the recording process stopped?)")
                time.sleep(_POLL_S)
            yield
        finally:
            os.close(fd)
