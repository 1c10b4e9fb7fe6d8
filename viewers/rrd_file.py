"""Writing a Rerun session to an .rrd file without hanging on a full disk, and saying why it failed.

Rerun's file sink writes in a thread of its own: a failed write (a full disk) stops that thread, shows only in
Rerun's log on stderr, and leaves a flush without a time limit waiting forever inside Rust, where Ctrl-C and SIGTERM
are not seen. `write_rrd` flushes a second at a time, holds stderr back meanwhile and turns Rerun's line about a
failed write into one error (`simreel.formats.durable.storage_error` for a full disk: exit 2). The file it writes is
a temporary one (`simreel.formats.targets.staged_output`), renamed by its caller when whole.
"""

from __future__ import annotations

import contextlib
import os
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simreel.errors import ViewError
from simreel.formats.durable import storage_error

__all__ = ["write_rrd", "first_line"]


def write_rrd(rec: Any, partial: Path, path: Path, blueprint: Any, log_to: Callable[[Any], None]) -> None:
    """Log a session (`log_to(rec)`, with its `blueprint`) into Rerun's file sink at `partial` and wait until all of
    it is written there; a failed write is one error naming `path`, the file the session is for."""
    replacing = path.exists()
    try:
        with _rerun_log_held() as log:
            try:
                rec.save(partial, default_blueprint=blueprint)
                log_to(rec)
                _flush_to_file(rec, path)
            finally:
                rec.disconnect()  # ends the file (its footer), or drops a sink whose writer stopped
    except ViewError as stopped:
        raise _write_failure(log, path, replacing=replacing) or stopped from None
    failure = _write_failure(log, path, replacing=replacing)  # a write that failed as the file was ended
    if failure is not None:
        raise failure


def first_line(error: Exception) -> str:
    """The first line of an error's message (its type's name when it has none)."""
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


def _flush_to_file(rec: Any, path: Path, *, wait_s: float = 1.0) -> None:
    """Wait until everything logged to `rec` is in its file (the session saved to `path`).

    Rerun's flush without a time limit waits forever once its file writer has stopped (a full disk), inside Rust
    where Ctrl-C and SIGTERM are not seen. Waiting `wait_s` at a time lets signals through; a flush that fails
    before its time is up found the writer stopped (`ViewError`); one that runs out of time is a slow disk,
    waited for again."""
    while True:
        started = time.monotonic()
        try:
            rec.flush(timeout_sec=wait_s)
            return
        except RuntimeError as e:
            if time.monotonic() - started < wait_s / 2:
                raise ViewError(f"--save {path}: Rerun's file writer stopped ({first_line(e)}); the session was "
                                "not saved") from e


_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_RERUN_LOG_LINE = re.compile(r"^\S+Z\s+(?:ERROR|WARN|INFO|DEBUG|TRACE)\s+re_\w+")
"""A line of Rerun's own log, colour codes removed: ``2026-11-24T08:57:05.658318Z ERROR re_log_encoding::...``."""
_OS_ERROR = re.compile(r"\(os error (\d+)\)")


@dataclass
class _HeldLog:
    """The lines written to stderr (fd 2) while it was held (`_rerun_log_held`), colour codes removed."""

    lines: list[str] = field(default_factory=list)

    def write_failures(self) -> list[str]:
        """Rerun's lines that say its file writer failed to write."""
        return [line for line in self.lines if _RERUN_LOG_LINE.match(line) and "Failed to write" in line]


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
            try:
                yield log
                failed = False
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
                held.seek(0)
                log.lines = _ANSI.sub("", held.read().decode(errors="replace")).splitlines()
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
