"""A replay run's report as it grows, so an interrupted run (Ctrl-C, kill -9, a lost node) keeps every verdict it
reached and `--resume` replays only the rest.

`--report REPORT.json` streams the run into ``REPORT.jsonl`` — one JSON object per line, each flushed as it is
written — and writes ``REPORT.json``, the whole report as one document, from it when the run ends or is
interrupted. The lines, in order::

    {"type": "run", ...}      a run: simreel version, time, working folder, inputs, how many files it lists, the
                              options that decide the verdicts, tolerances; a resumed run adds its own, with the
                              same options (and replays the files the first run listed, no others)
    {"type": "file", ...}     an input recording: absolute path, size, mtime_ns, env id, episodes, error, limits
    {"type": "episode", ...}  one episode's verdict (`EpisodeReport.to_json`, with "file" and the "worker" that
                              replayed it), or why it could not be replayed (verdict "error")
    {"type": "note", ...}     what happened on the way ("text": a Ray worker died, its episodes were replayed again)
    {"type": "end"}           the run replayed every episode it had to

Each line ends with its own checksum (``"crc32"``, of the line's text before it), so a line changed since it was
written — one byte of a verdict — is found when the report is read: `read_log` refuses the report, naming the line,
as it does a line of an unknown kind, a verdict that is not one of `VERDICTS`, or a field of the wrong type. A
report written before lines carried checksums is refused too (its verdicts cannot be checked): replay again.

An episode listed twice (a retried Ray task) counts once: the first line wins. ``REPORT.json`` is
`RunTally.head` (totals, one entry per file) with an ``"episodes"`` list of the episode lines.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from simreel.errors import ReportFileError, StorageError
from simreel.io.durable import is_storage_error, storage_error
from simreel.io.lock import lock_file
from simreel.io.targets import open_text_atomic
from simreel.replay.report.report import EpisodeReport
from simreel.replay.report.tally import FileTally, RunTally
from simreel.verdicts.report_file import (
    Verdicts,
    numbered_lines,
    read_log,
    read_verdicts,
    report_paths,
    signed_line,
)

__all__ = ["ReportLog", "LoggedRun", "report_paths", "read_log", "load_log", "tally_of_log", "write_report",
           "read_verdicts", "Verdicts"]

_SYNC_SECONDS = 2.0
"""How often the log is fsync'ed (a flushed line already survives the death of the process; this is for the
machine's)."""


class ReportLog:
    """Appends a run's lines to REPORT.jsonl, holding an exclusive lock on it so two runs never write one report.

    `resume`: keep the lines there (dropping a last line a killed run left half-written); else start empty. A write
    the storage refuses (a full disk) raises `StorageError` saying what the lines kept and how to finish; the line
    it cut short is dropped by the resume.
    """

    def __init__(self, path: str | Path, *, resume: bool) -> None:
        self.path = Path(path)
        # unbuffered: a refused write leaves nothing waiting in a buffer that closing would write (and fail) again
        self._fh: IO[bytes] = open(self.path, "a+b", buffering=0)  # never truncates before the lock is held
        if not lock_file(self._fh, exclusive=True):
            self._fh.close()
            raise ReportFileError(self.path, "another simreel replay is writing this report now; wait for it to end")
        if resume:
            self._drop_cut_line()
        else:
            self._fh.truncate(0)
        self._synced = time.monotonic()
        self.episodes = 0
        """Episode lines this run wrote whole."""
        self._resumable = resume
        """Whether the lines hold a whole run line, which a resumed run starts from."""
        self._refused: StorageError | None = None

    def _drop_cut_line(self) -> None:
        self._fh.seek(0)
        data = self._fh.read()
        if data and not data.endswith(b"\n"):
            self._fh.truncate(data.rfind(b"\n") + 1)
        self._fh.seek(0, os.SEEK_END)

    def write(self, record: dict[str, Any]) -> None:
        data = signed_line(record)
        try:
            while data:
                data = data[self._fh.write(data):]
            if time.monotonic() - self._synced > _SYNC_SECONDS:
                os.fsync(self._fh.fileno())
                self._synced = time.monotonic()
        except OSError as e:
            raise self._refusal(e) from None
        self._resumable = self._resumable or record["type"] == "run"

    def _refusal(self, e: OSError) -> OSError | StorageError:
        """The one-line error for a write the storage refused: what the lines keep and how to finish the run (`e`
        itself when it is no storage error)."""
        if not is_storage_error(e):
            return e
        json_path = report_paths(self.path)[0]
        if self._resumable:
            kept = (f": it keeps every verdict reached before ({self.episodes} this run; the line cut short is "
                    "dropped when the run is resumed)")
            then = f"simreel replay --resume {json_path}"
        else:
            kept, then = ": it holds no run yet", "run it again with --overwrite"
        error = storage_error(self.path, e)
        self._refused = StorageError(self.path, error.reason, f"{error.fix}, then finish with: {then}", kept)
        return self._refused

    def episode(self, path: str, report: EpisodeReport, *, warnings: list[str], worker: str = "") -> None:
        """An episode's line: its report, the file's fingerprint warnings first met with it, who replayed it."""
        record = {"type": "episode", "file": path, **report.to_json(), "worker": worker}
        if warnings:
            record["warnings"] = warnings
        self.write(record)
        self.episodes += 1

    @property
    def refused(self) -> StorageError | None:
        """The storage error a write met (the lines end there), or None."""
        return self._refused

    def close(self) -> None:
        if self._fh.closed:
            return
        try:
            if self._refused is None:
                os.fsync(self._fh.fileno())
        except OSError as e:
            raise self._refusal(e) from None
        finally:
            self._fh.close()  # releases the lock

    def __enter__(self) -> ReportLog:
        return self

    def __exit__(self, *exc: object) -> None:
        if exc[0] is None:
            self.close()
            return
        with contextlib.suppress(OSError, StorageError):  # the error raised in the block is the one to tell
            self.close()



@dataclass
class LoggedRun:
    """What a report's lines say about the run that wrote them: its first run line, its files, what is done."""

    run: dict[str, Any]
    files: dict[str, dict[str, Any]] = field(default_factory=dict)
    file_lines: dict[str, int] = field(default_factory=dict)
    """Path → the number of the line that lists it."""
    done: dict[tuple[str, int], int] = field(default_factory=dict)
    """(path, index) of each episode with a verdict → the number of its line."""
    ended: bool = False

    def add(self, path: Path, number: int, record: dict[str, Any]) -> None:
        """Take the report's line `number`; `ReportFileError` for a verdict on a file no line before it lists."""
        kind = record["type"]
        if kind == "file":
            self.files.setdefault(record["path"], record)
            self.file_lines.setdefault(record["path"], number)
        elif kind == "episode":
            if record["file"] not in self.files:
                raise ReportFileError(path, f"line {number} gives a verdict on {record['file']}, which no line before "
                                            "it lists as a file of the run: the report is damaged")
            self.done.setdefault((record["file"], record["index"]), number)
        self.ended = kind == "end" or (self.ended and kind != "run")


def load_log(path: str | Path) -> LoggedRun:
    """Read a report's lines for `--resume`; `ReportFileError` when it is not a replay report or a line is damaged."""
    logged: LoggedRun | None = None
    for number, record in numbered_lines(path):
        if logged is None:
            if record["type"] != "run":
                raise ReportFileError(path, "does not start with a run line: not a simreel replay report")
            logged = LoggedRun(record)
        logged.add(Path(path), number, record)
    if logged is None:
        raise ReportFileError(path, "is empty: the run that made it wrote nothing; start a new one")
    return logged


def tally_of_log(path: str | Path) -> RunTally:
    """The totals of the report's lines (read one at a time)."""
    tally: RunTally | None = None
    for record in read_log(path):
        kind = record["type"]
        if kind == "run" and tally is None:
            tally = RunTally(record["options"]["mode"], record["options"].get("resync"), record["tolerances"])
        elif tally is None:
            raise ReportFileError(path, "does not start with a run line: not a simreel replay report")
        elif kind == "file":
            tally.add_file(FileTally.from_json(record))
        elif kind == "episode":
            tally.add(record["file"], EpisodeReport.from_json(record), record.get("warnings", ()))
        elif kind == "note":
            tally.notes.append(record["text"])
    if tally is None:
        raise ReportFileError(path, "is empty: the run that made it wrote nothing")
    return tally


def _episode_lines(path: Path) -> Iterator[dict[str, Any]]:
    seen: set[tuple[str, int]] = set()
    for record in read_log(path):
        if record["type"] == "episode" and (record["file"], record["index"]) not in seen:
            seen.add((record["file"], record["index"]))
            yield {k: v for k, v in record.items() if k != "type"}


def write_report(log: str | Path, report: str | Path, *, output: str | None = None) -> RunTally:
    """Write the report document REPORT.json from its lines, episode by episode (atomically: a reader sees the
    old document or the new one); returns the run's totals."""
    tally = tally_of_log(log)
    head = tally.head()
    head["output"] = output
    text = json.dumps(head, indent=2)
    with open_text_atomic(report) as fh:
        fh.write(text[: text.rindex("}")].rstrip() + ',\n  "episodes": [')
        for k, record in enumerate(_episode_lines(Path(log))):
            fh.write(("," if k else "") + "\n    " + json.dumps(record, separators=(",", ":")))
        fh.write("\n  ]\n}\n")
    return tally
