"""Reading a replay report: the checked lines of REPORT.jsonl (each ends with its own CRC-32 checksum; a line
changed since it was written, of an unknown kind, with a verdict none of `REPORT_VERDICTS` or a field of the wrong
type is refused, naming it) and the verdicts a report gives each episode (`read_verdicts`), from its lines or from
the REPORT.json document. Writing it is the replay room's (`simreel.replay.report.log`); what reads verdicts to
choose episodes (`simreel filter`, the training dataset, `simreel export`) reads them here."""

from __future__ import annotations

import json
import re
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simreel.errors import ReportFileError, UsageError
from simreel.model.json_input import parse_json
from simreel.verdicts.compare import VERDICTS

__all__ = ["REPORT_VERDICTS", "VERIFIED", "Verdicts", "report_paths", "signed_line", "numbered_lines", "read_log",
           "read_verdicts"]

REPORT_VERDICTS = (*VERDICTS, "error")
"""Every verdict a replay report gives an episode: judged, or ``error`` (it could not be replayed)."""
VERIFIED = ("exact", "within_tolerance")
"""The verdicts of an episode a replay verified."""


def report_paths(report: str | Path) -> tuple[Path, Path]:
    """(REPORT.json, REPORT.jsonl) of `--report` / `--resume` given either one."""
    p = Path(report)
    if p.suffix == ".jsonl":
        return p.with_suffix(".json"), p
    if p.suffix != ".json":
        raise UsageError(f"{p}: a report is a .json file (its lines stream into {p.name}.jsonl beside it while the "
                         "run goes); name it REPORT.json")
    return p, p.with_name(p.name + "l")



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
    if kind == "episode" and record["verdict"] not in REPORT_VERDICTS:
        verdict = json.dumps(record["verdict"])[:40]
        return f"gives the verdict {verdict}, which is none of {', '.join(REPORT_VERDICTS)}"
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
        if e["verdict"] not in REPORT_VERDICTS:
            raise ReportFileError(json_path, f"episode {e['index']} of {e['file']} has the verdict "
                                             f"{json.dumps(e['verdict'])[:40]}, which is none of "
                                             f"{', '.join(REPORT_VERDICTS)}: "
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
