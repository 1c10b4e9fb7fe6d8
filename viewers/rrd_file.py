"""Writing a Rerun session to an .rrd file without hanging on a full disk, and saying why it failed.

Rerun's file sink writes in a thread of its own: a failed write (a full disk) stops that thread, shows only in
Rerun's log on stderr, and leaves a flush waiting forever inside Rust, where Ctrl-C and SIGTERM are not seen — a
flush given a time limit too (rerun-sdk 0.41: a 600 KiB disk, a 5.7 MB session). `write_rrd` holds stderr back while
it writes, flushes in a thread of its own and waits in Python, watching Rerun's log: a line about a failed write ends
the wait with one error (`simreel.io.durable.storage_error` for a full disk: exit 2), leaving the stuck flush
behind. The file it writes is a temporary one (`simreel.io.targets.staged_output`), renamed by its caller when
whole. (Rerun's in-memory binary stream would avoid the writer thread, but it must be read whole — reads in parts
concatenate into a file Rerun's reader rejects — and a session with camera frames is as big as its frames.)
"""

from __future__ import annotations

import contextlib
import os
import re
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simreel.errors import ViewError
from simreel.io.durable import storage_error

__all__ = ["write_rrd", "first_line"]


def write_rrd(rec: Any, partial: Path, path: Path, blueprint: Any, log_to: Callable[[Any], None]) -> None:
    """Log a session (`log_to(rec)`, with its `blueprint`) into Rerun's file sink at `partial` and wait until all of
    it is written there; a failed write is one error naming `path`, the file the session is for."""
    replacing = path.exists()
    with _rerun_log_held() as log:
        rec.save(partial, default_blueprint=blueprint)
        try:
            log_to(rec)
            _flush_to_file(rec, log)
        except _WriterStopped as stopped:
            _abandon(rec)
            log.write_failures(refresh=True)
            raise _write_failure(log, path, replacing=replacing) or ViewError(
                f"--save {path}: Rerun's file writer stopped ({stopped}); the session was not saved") from None
        except BaseException:
            rec.disconnect()
            raise
        rec.disconnect()  # ends the file (its footer)
    failure = _write_failure(log, path, replacing=replacing)  # a write that failed as the file was ended
    if failure is not None:
        raise failure


def first_line(error: Exception) -> str:
    """The first line of an error's message (its type's name when it has none)."""
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


class _WriterStopped(Exception):
    """Rerun's file writer stopped: its log says a write failed (the flush waiting for it never returns), or the
    flush raised."""


def _flush_to_file(rec: Any, log: _HeldLog, *, poll_s: float = 0.05) -> None:
    """Wait until everything logged to `rec` is in its file, in Python (signals seen), while a thread flushes;
    `_WriterStopped` once Rerun's held log (`log`) says a write failed, or when the flush raised."""
    finished = threading.Event()
    raised: list[Exception] = []

    def flush() -> None:
        try:
            rec.flush()
        except Exception as e:  # noqa: BLE001 - handed to the waiting thread
            raised.append(e)
        finally:
            finished.set()

    threading.Thread(target=flush, name="simreel-rerun-flush", daemon=True).start()
    while not finished.wait(poll_s):
        if log.write_failures(refresh=True):
            raise _WriterStopped
    if raised:
        raise _WriterStopped(first_line(raised[0]))


def _abandon(rec: Any, *, wait_s: float = 2.0) -> None:
    """Leave a recording whose file writer stopped: disconnecting it, or Rerun's own shutdown at exit, can wait for
    that writer forever (the flush thread already does, a daemon thread that dies with the process). Its sink is
    swapped for one in memory, in a thread waited for `wait_s` at most, so that dropping it later neither waits nor
    logs the dead writer's error past the held log."""
    import rerun as rr

    rr.unregister_shutdown()
    swap = threading.Thread(target=rec.memory_recording, name="simreel-rerun-abandon", daemon=True)
    swap.start()
    swap.join(wait_s)


_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_RERUN_LOG_LINE = re.compile(r"^\S+Z\s+(?:ERROR|WARN|INFO|DEBUG|TRACE)\s+re_\w+")
"""A line of Rerun's own log, colour codes removed: ``2026-11-24T08:57:05.658318Z ERROR re_log_encoding::...``."""
_OS_ERROR = re.compile(r"\(os error (\d+)\)")


@dataclass
class _HeldLog:
    """The lines written to stderr (fd 2) while it was held (`_rerun_log_held`), colour codes removed."""

    lines: list[str] = field(default_factory=list)
    fd: int = -1
    """The file fd 2 writes to while held (-1 once it is over and `lines` are final)."""

    def write_failures(self, *, refresh: bool = False) -> list[str]:
        """Rerun's lines that say its file writer failed to write (`refresh`: read what was written so far)."""
        if refresh and self.fd >= 0:
            self.lines = _lines(_read_all(self.fd))
        return [line for line in self.lines if _RERUN_LOG_LINE.match(line) and "Failed to write" in line]


def _read_all(fd: int) -> bytes:
    """All of the file `fd`, read without moving its offset (the writers of fd 2 share it)."""
    return os.pread(fd, os.fstat(fd).st_size, 0)


def _lines(held: bytes) -> list[str]:
    return _ANSI.sub("", held.decode(errors="replace")).splitlines()


@contextlib.contextmanager
def _rerun_log_held() -> Iterator[_HeldLog]:
    """Hold back what is written to stderr (fd 2, where Rerun's threads log) while the block runs, then write it
    out; Rerun's own lines are left out when the block raised or they say a write failed: the error raised for it
    says what they said (one line, not Rerun's log)."""
    import sys
    import tempfile

    log = _HeldLog()
    sys.stderr.flush()
    saved = os.dup(2)
    failed = True
    try:
        with tempfile.TemporaryFile() as held:
            os.dup2(held.fileno(), 2)
            log.fd = held.fileno()
            try:
                yield log
                failed = False
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
                log.lines, log.fd = _lines(_read_all(held.fileno())), -1
                drop = failed or bool(log.write_failures())
                for line in log.lines:
                    if not (drop and _RERUN_LOG_LINE.match(line)):
                        print(line, file=sys.stderr)
    finally:
        os.close(saved)


def _write_failure(log: _HeldLog, path: Path, *, replacing: bool) -> Exception | None:
    """The error for a write that Rerun's file writer said failed (`_HeldLog.write_failures`), or None: a full disk
    or another storage error (`storage_error`: exit 2), else `ViewError` with Rerun's words."""
    failures = log.write_failures()
    if not failures:
        return None
    lost = "the session was not saved" + (" (the file there is unchanged)" if replacing else "")
    code = _OS_ERROR.search(failures[0])
    if code is not None:
        number = int(code.group(1))
        return storage_error(path, OSError(number, os.strerror(number)), lost=lost)
    said = failures[0].split(": ", 1)[-1]
    return ViewError(f"--save {path}: Rerun could not write the file ({said}); {lost}")
