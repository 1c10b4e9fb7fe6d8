"""What keeps a commit whole: no signal handled in its middle, disk space reserved before it writes, and the
errors of the storage (a full disk, a read-only file system) turned into one-line errors.

A commit that stopped half way could leave a file with an episode half written; so a writer runs each commit
inside `deferred_signals` (a Ctrl-C or SIGTERM that arrives then is handled right after it) and first
`reserve_space` for everything the commit may write, so a full disk refuses the commit before the file is
touched, and after it `release_unused` the part of that reservation it did not use. `storage_error` words the
`OSError` a write raised. And what keeps a command's stop a stop: `stopping_signals` / `raise_if_stopped`, for a
Ctrl-C that Python swallowed.
"""

from __future__ import annotations

import _signal  # signal's C functions: `signal.signal` adds enum conversions, ~4 µs a call
import contextlib
import ctypes
import errno
import functools
import os
import re
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from simreel.errors import StorageError, Terminated

__all__ = ["deferred_signals", "stopping_signals", "raise_if_stopped", "stop_raised", "reserve_space", "release_space",
           "release_unused", "storage_error", "errno_of", "is_storage_error", "STORAGE_ERRNOS"]

_DEFERRED = (signal.SIGINT, signal.SIGTERM)

STORAGE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO,
                            errno.EFBIG})
"""Errors of the storage rather than of simreel: reported as bad input (exit 2), never as an internal error."""


def is_storage_error(e: BaseException) -> bool:
    """Whether `e` is the storage refusing a write (full, read-only, no permission, failing), not a bug."""
    return isinstance(e, OSError) and errno_of(e) in STORAGE_ERRNOS


@contextmanager
def deferred_signals(*, handled_only: bool = False) -> Iterator[list[int]]:
    """Hold SIGINT and SIGTERM until the block has finished, then handle them as they would have been; yields the
    list of the signals held so far (a block that waits can give up waiting once one is there).

    `handled_only`: hold only a signal that a Python handler takes (one that would raise in the block's middle), for
    a block that must not be cut half way by an exception but may end with its process: a signal left to the system
    (its default ends the process at once, nothing half made survives it) then acts at once.

    When the block raises, its own error wins: a held signal is noted for `raise_if_stopped` instead of raising over
    it (a KeyboardInterrupt must not hide, say, the full disk that stopped a commit). Only the main thread can
    handle signals; elsewhere (and for a handler Python did not install) nothing is deferred. A block inside another
    holds nothing more: the outer one holds the signals, yields its list and handles them when it ends (a recorder's
    reset runs a dozen nested blocks; the handlers are swapped once).
    """
    global _holding
    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    if _holding is not None:
        yield from _nested(_holding)
        return
    caught: list[int] = []
    previous = {s: _signal.getsignal(s) for s in _DEFERRED}
    held = [s for s, handler in previous.items() if (callable(handler) if handled_only else handler is not None)]
    if not held:
        yield []
        return
    for s in held:
        _signal.signal(s, lambda signum, frame: caught.append(signum))
    _holding, failed = caught, False
    try:
        yield caught
    except BaseException:
        failed = True
        raise
    finally:
        _holding = None
        for s in held:
            _signal.signal(s, previous[s])
        if failed:
            _received.extend(caught)
        else:
            for s in caught:
                signal.raise_signal(s)


_holding: list[int] | None = None
"""The list of signals caught by the main thread's `deferred_signals` block running now, if one is."""


def _nested(holding: list[int]) -> Iterator[list[int]]:
    """A block inside another (`deferred_signals`): when it raises, the signals that came during it are noted for
    `raise_if_stopped` rather than raised when the outer block ends, as its own block would have done."""
    before = len(holding)
    try:
        yield holding
    except BaseException:
        _received.extend(holding[before:])
        del holding[before:]
        raise


# ------------------------------------------------------------------ signals that must stop a command
# Python raises a signal's exception wherever the main thread happens to be. When that is a finalizer or a weakref
# callback run by the garbage collector, Python prints "Exception ignored in ..." and goes on: a replay asked to
# stop would run to its end and exit 0. `stopping_signals` (the CLI holds it around every command) notes each
# signal before raising; loops between units of work call `raise_if_stopped`, which raises it again.

_received: list[int] = []


def _exception(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


_raised: list[int] = []
"""The signals `stopping_signals` raised as exceptions (each also in `_received`): one that never reached the command's
handler was swallowed on the way (`stop_raised`)."""


def _on_signal(signum: int, frame: Any) -> None:
    _received.append(signum)
    _raised.append(signum)
    raise _exception(signum)


@contextmanager
def stopping_signals() -> Iterator[None]:
    """SIGINT raises KeyboardInterrupt and SIGTERM `Terminated`, each noted for `raise_if_stopped`; the previous
    handlers are put back after. Only the main thread handles signals: elsewhere this changes nothing.

    Meanwhile Python's report of an exception it could not raise ("Exception ignored in ...", with a traceback on
    stderr) is left out for these two: raised in a finalizer or a weakref callback, the signal is noted all the same,
    and the command's one line says it was stopped."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    previous_hook = sys.unraisablehook

    def unraisable(report: Any) -> None:
        if not isinstance(report.exc_value, KeyboardInterrupt):  # Terminated is one too
            previous_hook(report)

    sys.unraisablehook = unraisable
    try:
        yield
    finally:
        sys.unraisablehook = previous_hook
        for s, handler in previous.items():
            signal.signal(s, handler)
        _received.clear()
        _raised.clear()


def raise_if_stopped() -> None:
    """Raise the exception of a signal received inside `stopping_signals` (again, if it was swallowed)."""
    if _received:
        raise _exception(_received[0])


def stop_raised() -> KeyboardInterrupt | None:
    """The exception (KeyboardInterrupt, or `Terminated` for SIGTERM) of the first signal `stopping_signals` raised, or
    None. Not one a `deferred_signals` block held while its own error went on: that error wins."""
    return _exception(_raised[0]) if _raised else None


def reserve_space(fd: int, nbytes: int) -> None:
    """Allocate `nbytes` of disk past the end of the file open as `fd`, so that writing that much cannot fail
    for lack of space; raises `OSError` (ENOSPC) when the disk has not got them.

    The blocks are allocated without changing the file's size (Linux `fallocate` with FALLOC_FL_KEEP_SIZE), so
    the file never holds more than its data and nothing has to be cut back after the commit: growing the file into
    blocks already allocated costs microseconds, while freeing blocks that `posix_fallocate` added costs ~1.6 ms
    a commit on ext4. What a commit leaves unused is used by the next one; `release_space` gives back the rest.
    Where the system has no such call, `posix_fallocate` reserves them: the file grows, and HDF5 does not cut
    it back (its file driver never learns of bytes it did not write itself); `release_unused` does.
    """
    size = os.fstat(fd).st_size
    try:
        _allocate(fd, size, max(1, nbytes))
    except OSError as e:
        if e.errno in _CANNOT_RESERVE:
            return  # the file system cannot reserve: the commit then finds out while it writes
        os.ftruncate(fd, size)  # what was allocated before the failure
        raise


def release_space(fd: int) -> None:
    """Give back the blocks `reserve_space` allocated past the end of the file open as `fd` (a truncation to its
    own size frees them)."""
    os.ftruncate(fd, os.fstat(fd).st_size)


_CANNOT_RESERVE = (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS)
_FALLOC_FL_KEEP_SIZE = 1


@functools.cache
def _fallocate() -> Any:
    """libc's `fallocate(fd, mode, offset, len)`, or None where there is none (not Linux)."""
    try:
        call = ctypes.CDLL(None, use_errno=True).fallocate
    except (OSError, AttributeError):
        return None
    call.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    call.restype = ctypes.c_int
    return call


def _allocate(fd: int, offset: int, length: int) -> None:
    """Allocate `length` bytes of disk at `offset` of `fd`, keeping the file's size where the system can."""
    call = _fallocate()
    while call is not None:
        if call(fd, _FALLOC_FL_KEEP_SIZE, offset, length) == 0:
            return
        code = ctypes.get_errno()
        if code in _CANNOT_RESERVE:
            break  # this file system has no FALLOC_FL_KEEP_SIZE: reserve by growing the file
        if code != errno.EINTR:
            raise OSError(code, os.strerror(code))
    os.posix_fallocate(fd, offset, length)


def release_unused(fd: int, end: int) -> None:
    """Cut the file open as `fd` at `end` (where the writer's data ends) if it is longer: what a `reserve_space`
    that had to grow the file (no FALLOC_FL_KEEP_SIZE) reserved and the commit did not use. Left in place, that
    is up to an episode's raw size of zeros at the end of the file (measured with `posix_fallocate`: 114 KB of a
    226 KB conversion output). A failure to cut only leaves those bytes, so it is ignored."""
    with contextlib.suppress(OSError):
        if os.fstat(fd).st_size > end:
            os.ftruncate(fd, end)


def errno_of(e: OSError) -> int | None:
    """The errno of `e`, also when h5py raised it without one and only HDF5's message names it ("errno = 28")."""
    if e.errno is not None:
        return e.errno
    found = re.search(r"errno = (\d+)", str(e))
    return int(found.group(1)) if found else None


def storage_error(path: Path, e: OSError, *, committed: int | None = None, lost: str = "",
                  readable: str = "") -> StorageError:
    """The one-line error for `e`, raised while writing the recording `path`: what happened and what to do.

    `committed`: episodes already in the file, which stay readable (`readable`: how, when it takes a step);
    `lost`: what this failure lost."""
    code = errno_of(e)
    if code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        reason = "the disk is full" if code == errno.ENOSPC else f"cannot grow the file ({os.strerror(code)})"
        fix = "free some space or write to another disk"
    elif code == errno.EROFS:
        reason, fix = "the file system is read-only", "write to another folder"
    elif code in (errno.EACCES, errno.EPERM):
        reason, fix = f"permission denied ({os.strerror(code)})", "write to a folder you may write to"
    else:
        reason, fix = f"cannot write ({e.strerror or e})", "check the disk"
    detail = f": {lost}" if lost else ""
    if committed is not None:
        detail += f"; the {committed} episode(s) committed before stay readable{readable}"
    return StorageError(path, reason, fix, detail)
