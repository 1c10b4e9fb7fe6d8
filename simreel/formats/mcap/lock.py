"""The advisory lock a `McapWriter` holds for its whole life, so a reader can tell a file that is still being
written from one whose recording process died (the kernel drops the locks of a dead process)."""

from __future__ import annotations

from pathlib import Path
from typing import IO

__all__ = ["lock_file", "being_written"]


def lock_file(fh: IO[bytes], *, exclusive: bool) -> bool:
    """Take an advisory lock without waiting; False if another open file holds it (True where unsupported).

    A shared lock is only a probe: it is released at once.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return True
    try:
        fcntl.flock(fh.fileno(), (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError:  # pragma: no cover - file systems without flock
        return True
    if not exclusive:
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
    return True


def being_written(path: str | Path) -> bool:
    """True while a `McapWriter` (in any process) has `path` open."""
    try:
        with open(path, "rb") as fh:
            return not lock_file(fh, exclusive=False)
    except OSError:
        return False
