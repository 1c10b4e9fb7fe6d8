"""What a path names on disk, told the same way by every command: a symbolic link loop (`is_symlink_loop`,
`SYMLINK_LOOP`), the real file behind a path (`real_path`), and a recording opened for reading (`open_for_reading`,
`read_head`), where the file system's refusal (no permission, a failing disk) is a `RecordingFileError` naming the
file and why: bad input, never an internal error.

A symbolic link loop names no file at all, and Python tells it apart from a missing file in no one way: in 3.11
`Path.resolve` raises `RuntimeError` for one, `Path.is_file` and `Path.exists` answer False as for a missing file.
So the test and the words for it live here, once, for the files a command reads and those it writes.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import BinaryIO

from simreel.errors import RecordingFileError
from simreel.options.checks import refuse_empty

__all__ = ["SYMLINK_LOOP", "refuse_empty", "is_symlink_loop", "real_path", "file_key", "read_problem", "open_for_reading",
           "read_head"]

SYMLINK_LOOP = "a symbolic link loop (following its links never reaches a file); fix or remove the link"
"""What a path that runs into a symbolic link loop is, in the one line a command prints for it."""


def is_symlink_loop(path: str | os.PathLike[str]) -> bool:
    """Whether `path` runs into a symbolic link loop: it, or a folder on its way, is a link that leads back to itself
    (or through more links than the system follows: the same ELOOP)."""
    try:
        os.stat(path)
    except OSError as e:
        return e.errno == errno.ELOOP
    return False


def real_path(path: str | os.PathLike[str]) -> Path:
    """The absolute path of the file `path` names, every link followed, as `Path.resolve` gives it; for a path that
    runs into a symbolic link loop, the path as far as it resolves, where `Path.resolve` raises. What asks whether
    two paths are one file must not fail on a loop: the command says what the loop is where it reads or writes it."""
    return Path(os.path.realpath(path))


def file_key(path: str | os.PathLike[str]) -> tuple[int, int] | Path:
    """What two paths share when they name one file: its device and inode where it exists (a hard link, a symbolic
    link and another spelling of its path all give the same), else the path as far as it resolves (`real_path`: a
    file not written yet, a link loop). What decides that a file is "given twice", or that an output is an input."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return real_path(path)
    return (st.st_dev, st.st_ino)


def read_problem(code: int | None) -> str | None:
    """Why a file cannot be read, for the errno `code` of the file system's refusal to open or read it (no
    permission, a link loop, a failing disk); None for a code that says nothing about that (a reader then words the
    error itself)."""
    if code in (errno.EACCES, errno.EPERM):
        return "permission denied (this user may not read it)"
    if code == errno.ELOOP:
        return SYMLINK_LOOP
    if code == errno.ENOENT:
        return "no such file"
    if code == errno.EISDIR:
        return "a folder, not a recording file"
    if code in (errno.EIO, errno.ENXIO, errno.ESTALE):
        return f"cannot be read ({os.strerror(code)}); check the disk"
    return None


def _unreadable(path: str | os.PathLike[str], e: OSError) -> RecordingFileError:
    """The one-line error for `e`, raised while opening or reading the recording `path`."""
    return RecordingFileError(path, read_problem(e.errno) or f"cannot be read ({e.strerror or e})")


def open_for_reading(path: str | os.PathLike[str]) -> BinaryIO:
    """`path` opened for reading in binary; `RecordingFileError` naming the file and why when the file system refuses
    (`read_problem`): a recording this user may not read is bad input to fix, not a bug of simreel's."""
    try:
        return open(path, "rb")
    except OSError as e:
        raise _unreadable(path, e) from None


def read_head(path: str | os.PathLike[str], size: int) -> bytes:
    """The first `size` bytes of the file `path` (fewer for a shorter file): what tells its format apart.
    `RecordingFileError` as `open_for_reading`, also when reading them fails."""
    with open_for_reading(path) as fh:
        try:
            return fh.read(size)
        except OSError as e:
            raise _unreadable(path, e) from None
