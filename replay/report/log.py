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
import re
import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from simreel.errors import ReportFileError, StorageError, UsageError
from simreel.io.durable import is_storage_error, storage_error
from simreel.io.lock import lock_file
from simreel.io.targets import open_text_atomic
from simreel.model.json_input import parse_json
from simreel.replay.report.report import VERDICTS, EpisodeReport
from simreel.replay.report.tally import FileTally, RunTally

__all__ = ["ReportLog", "LoggedRun", "report_paths", "read_log", "load_log", "tally_of_log", "write_report",
           "read_verdicts", "Verdicts"]

_SYNC_SECONDS = 2.0
"""How often the log is fsync'ed (a flushed line already survives the death of the process; this is for the
machine's)."""


def report_paths(report: str | Path) -> tuple[Path, Path]:
    """(REPORT.json, REPORT.jsonl) of `--report` / `--resume` given either one."""
    p = Path(report)
    if p.suffix == ".jsonl":
        return p.with_suffix(".json"), p
    if p.suffix != ".json":
        raise UsageError(f"{p}: a report is a .json file (its lines stream into {p.name}.jsonl beside it while the "
                         "run goes); name it REPORT.json")
    return p, p.with_name(p.name + "l")


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


_CHECKSUM = re.compile(rb',"crc32":"([0-9a-f]{8})"}\n\Z')
"""The end of a line: its checksum, the CRC-32 of the line's text without it (`signed_line`)."""
_FIELDS: dict[str, dict[str, tuple[type, ...]]] = {
    "run": {"options": (dict,), "tolerances": (dict,), "inputs": (list,)},
    "file": {"path": (str,), "episodes": (int,), "error": (str, type(None))},
    "episode": {"file": (str,), "index": (int,), "length": (int,), "verdict": (str,)},
    "note": {"text": (str,)},
    "end": {},
}
"""Each kind of line, and the types of the fields the reader relies on."""
_JSON_TYPES = {dict: "an object", list: "an array", str: "text", int: "a whole number", float: "a number",
               bool: "true or false", type(None): "null"}


def signed_line(record: dict[str, Any]) -> bytes:
    """`record` as a line of REPORT.jsonl: compact JSON ending with its checksum."""
    body = json.dumps(record, separators=(",", ":")).encode("utf-8")
    return body[:-1] + b',"crc32":"%08x"}\n' % zlib.crc32(body)


def _checked_body(line: bytes) -> bytes | None:
    """The line's JSON without its checksum, or None when it has none or its checksum does not match its text."""
    found = _CHECKSUM.search(line)
    if found is None:
        return None
    body = line[: found.start()] + b"}"
    return body if b"%08x" % zlib.crc32(body) == found.group(1) else None


def _unchecked_problem(path: Path, line: bytes, number: int) -> str:
    """Why a line without a valid checksum is refused: a report of an earlier simreel, something else, damage."""
    if number == 1 and not _CHECKSUM.search(line):
        first = parse_json(line, path, what="line 1", error=ReportFileError)
        if isinstance(first, dict) and first.get("type") == "run":
            return ("was written by an earlier simreel, whose report lines carry no checksum, so its verdicts "
                    "cannot be checked; replay again with --report (--overwrite replaces it)")
        return "line 1 is not a report line: not a simreel replay report"
    return (f"line {number} is damaged (its checksum does not match its text: it changed since it was written), so "
            "no verdict of the report can be trusted; replay again with --report (--overwrite replaces it)")


def _line_problem(record: Any) -> str | None:
    """What is wrong with a line's fields (its kind, a field's type, its verdict), or None."""
    kind = record.get("type") if isinstance(record, dict) else None
    if kind not in _FIELDS:
        return "is not a report line (no known \"type\")"
    for name, types in _FIELDS[kind].items():
        value = record.get(name)
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            return (f"has {_JSON_TYPES.get(type(value), 'a value')} as \"{name}\", which in {kind} lines is "
                    f"{_JSON_TYPES[types[0]]}")
    if kind == "episode" and record["verdict"] not in VERDICTS:
        return f"gives the verdict {json.dumps(record['verdict'])[:40]}, which is none of {', '.join(VERDICTS)}"
    return None


def numbered_lines(path: str | Path) -> Iterator[tuple[int, dict[str, Any]]]:
    """(line number, object) of each line of REPORT.jsonl, checked (`read_log`), in order."""
    p = Path(path)
    if not p.is_file():
        raise ReportFileError(p, "no such report (a run with --report REPORT.json streams into REPORT.jsonl)")
    with open(p, "rb") as fh:
        for number, line in enumerate(fh, 1):
            if not line.endswith(b"\n"):
                return  # cut mid-write: that episode had not finished writing; a resumed run replays it
            body = _checked_body(line)
            if body is None:
                raise ReportFileError(p, _unchecked_problem(p, line, number))
            record = parse_json(body, p, what=f"line {number}", error=ReportFileError)
            problem = _line_problem(record)
            if problem is not None:
                raise ReportFileError(p, f"line {number} {problem}: the report is damaged or not a replay report")
            yield number, record


def read_log(path: str | Path) -> Iterator[dict[str, Any]]:
    """The lines of REPORT.jsonl as objects (without their checksums), in order. A last line cut short (a killed
    run) is skipped; a line before it that is damaged (its checksum does not match), not JSON, or not a report
    line of the right types raises `ReportFileError` naming it."""
    for _, record in numbered_lines(path):
        yield record


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


@dataclass
class Verdicts:
    """A replay report's verdicts: (absolute path, index) → verdict, and each file's (size, mtime_ns) then."""

    verdicts: dict[tuple[str, int], str]
    files: dict[str, tuple[int | None, int | None]]


@contextmanager
def _report_records(report: Path) -> Iterator[Iterator[dict[str, Any]]]:
    """The report's file and episode entries: from its lines when they are there (they are the source), else
    from the document."""
    json_path, log = report_paths(report)
    if log.is_file():
        yield read_log(log)
        return
    if not json_path.is_file():
        raise ReportFileError(report, "no such report")
    yield iter(_document_records(json_path))


_REPLAY_REPORT = "--verified and --diverged take the report that `simreel replay --report REPORT.json` writes"


def _document_records(json_path: Path) -> list[dict[str, Any]]:
    """The file and episode entries of the report document `json_path`; `ReportFileError` saying what the file is
    instead (not JSON, a conversion's report, another JSON document) and which report to give."""
    doc = parse_json(json_path.read_bytes(), json_path, what="it", error=ReportFileError,
                     then=f"not a simreel replay report; {_REPLAY_REPORT}")
    try:
        files = [{"type": "file", **f, "path": str(f["path"])} for f in doc["files"]]
        episodes = [{"type": "episode", **e, "file": str(e["file"]), "index": int(e["index"]),
                     "verdict": str(e["verdict"])} for e in doc["episodes"]]
    except (KeyError, TypeError, ValueError):
        raise ReportFileError(json_path, f"{_what_document(doc)}, not a replay report; {_REPLAY_REPORT}") from None
    for e in episodes:
        if e["verdict"] not in VERDICTS:
            raise ReportFileError(json_path, f"episode {e['index']} of {e['file']} has the verdict "
                                             f"{json.dumps(e['verdict'])[:40]}, which is none of {', '.join(VERDICTS)}: "
                                             "the report is damaged")
    return files + episodes


def _what_document(doc: Any) -> str:
    """What a JSON document that is no replay report is, as far as its keys tell."""
    if isinstance(doc, dict) and "conversion" in doc and "written" in doc:
        return "a conversion's report (`simreel convert --report`)"
    if isinstance(doc, dict) and "env_info" in doc:
        return "a recording's JSON sidecar (ManiSkill's trajectory JSON)"
    return "a JSON document without a replay report's files and episodes"


def read_verdicts(report: str | Path) -> Verdicts:
    """Every episode's verdict in a replay report (REPORT.json or its REPORT.jsonl; a report of an interrupted
    run holds the episodes it reached)."""
    out = Verdicts({}, {})
    with _report_records(Path(report)) as records:
        for record in records:
            if record["type"] == "file":
                out.files.setdefault(record["path"], (record.get("size"), record.get("mtime_ns")))
            elif record["type"] == "episode":
                out.verdicts.setdefault((record["file"], int(record["index"])), record["verdict"])
    return out
