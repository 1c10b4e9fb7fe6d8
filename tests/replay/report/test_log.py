"""A run's streaming report (`simreel.replay.report.log`): lines flushed as they come, a line cut by a kill is
dropped (never misread), a damaged line is named, two runs never write one report, and the report document and
the verdicts are read back from the lines."""

from __future__ import annotations

import json
import re
import zlib

import pytest

from simreel.errors import ReportFileError, UsageError
from simreel.replay.report.log import (
    ReportLog,
    load_log,
    read_log,
    read_verdicts,
    report_paths,
    signed_line,
    write_report,
)
from simreel.replay.report.report import EpisodeReport
from simreel.replay.report.tally import FileTally

RUN = {"type": "run", "options": {"mode": "actions", "resync": None}, "tolerances": {"pos": 1e-5}, "inputs": ["/d"]}


def _episode(index: int, verdict: str = "exact") -> EpisodeReport:
    return EpisodeReport(index=index, seed=index, length=5, verdict=verdict, first_divergence=None, max_abs_error={})


def _log(path, *episodes: tuple[str, int, str]) -> None:
    with ReportLog(path, resume=False) as log:
        log.write(RUN)
        for name in sorted({f for f, *_ in episodes}):
            log.write({"type": "file", **FileTally(name, "PickCube-v1", 3, size=1, mtime_ns=2).to_json()})
        for name, index, verdict in episodes:
            log.episode(name, _episode(index, verdict), warnings=[])


def test_report_paths_pair_the_document_and_its_lines(tmp_path):
    assert report_paths(tmp_path / "r.json") == (tmp_path / "r.json", tmp_path / "r.jsonl")
    assert report_paths(tmp_path / "r.jsonl") == (tmp_path / "r.json", tmp_path / "r.jsonl")
    with pytest.raises(UsageError, match="a report is a .json file"):
        report_paths(tmp_path / "r.txt")


def test_a_line_cut_by_a_kill_is_dropped_and_resuming_appends_after_the_last_whole_line(tmp_path):
    path = tmp_path / "r.jsonl"
    _log(path, ("/d/a.h5", 0, "exact"), ("/d/a.h5", 1, "diverged"))
    whole = path.read_text()
    path.write_text(whole + '{"type":"episode","file":"/d/a.h5","ind')  # kill -9 mid-write
    assert set(load_log(path).done) == {("/d/a.h5", 0), ("/d/a.h5", 1)}
    with ReportLog(path, resume=True) as log:
        log.episode("/d/a.h5", _episode(2), warnings=[])
    assert path.read_text().startswith(whole) and len(list(read_log(path))) == 5


def test_a_damaged_line_is_named(tmp_path):
    path = tmp_path / "r.jsonl"
    _log(path, ("/d/a.h5", 0, "exact"))
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join([lines[0], "{not json\n", *lines[1:]]))
    with pytest.raises(ReportFileError, match="line 2 is damaged"):
        load_log(path)
    path.write_bytes(signed_line({"type": "episode", "file": "x", "index": 0, "length": 1, "verdict": "exact"}))
    with pytest.raises(ReportFileError, match="does not start with a run line"):
        load_log(path)


def test_a_byte_changed_in_a_verdict_is_found_by_the_lines_checksum(tmp_path):
    path = tmp_path / "r.jsonl"
    _log(path, ("/d/a.h5", 0, "exact"), ("/d/a.h5", 1, "diverged"))
    path.write_bytes(path.read_bytes().replace(b'"verdict":"diverged"', b'"verdict":"divergeX"'))
    damaged = f"{path}: line 4 is damaged (its checksum does not match its text: it changed since it was written)"
    with pytest.raises(ReportFileError, match=re.escape(damaged)):
        load_log(path)
    with pytest.raises(ReportFileError, match=re.escape(damaged)):
        read_verdicts(tmp_path / "r.json")  # filter --verified reads the same lines
    path.write_bytes(path.read_bytes().replace(b'"divergeX"', b'"diverg\xe9d"'))  # no UTF-8 text either
    with pytest.raises(ReportFileError, match="line 4 is damaged"):
        load_log(path)


EPISODE = {"type": "episode", "file": "/d/a.h5", "index": 0, "length": 5, "verdict": "exact"}


@pytest.mark.parametrize(("line", "problem"), [
    ({**EPISODE, "verdict": "divergeX"}, 'line 3 gives the verdict "divergeX", which is none of exact, '
                                         "within_tolerance, diverged, error"),
    ({**EPISODE, "index": "0"}, 'line 3 has text as "index", which in episode lines is a whole number'),
    ({**EPISODE, "index": True}, 'line 3 has true or false as "index", which in episode lines is a '
                                    "whole number"),
    ({**EPISODE, "type": "verdict"}, 'line 3 is not a report line (no known "type")'),
    ({**EPISODE, "file": "/d/b.h5"}, "line 3 gives a verdict on /d/b.h5, which no line before it lists as a file "
                                     "of the run"),
    (EPISODE, None),
])
def test_a_line_of_the_wrong_kind_or_types_is_named_though_its_checksum_matches(tmp_path, line, problem):
    path = tmp_path / "r.jsonl"
    _log(path)
    with ReportLog(path, resume=True) as log:
        log.write({"type": "file", **FileTally("/d/a.h5", "PickCube-v1", 3).to_json()})
        log.write(line)
    if problem is None:
        assert set(load_log(path).done) == {("/d/a.h5", 0)}
        return
    with pytest.raises(ReportFileError, match=re.escape(f"{path}: {problem}")):
        load_log(path)


def test_a_line_nested_too_deeply_is_named(tmp_path):
    path = tmp_path / "r.jsonl"
    _log(path)
    body = b'{"type":"note","text":"x","deep":' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    path.write_bytes(path.read_bytes() + body[:-1] + b',"crc32":"%08x"}\n' % zlib.crc32(body))
    with pytest.raises(ReportFileError, match=re.escape(f"{path}: line 2 is nested more than 100 levels deep")):
        load_log(path)


def test_a_report_of_an_earlier_simreel_without_checksums_is_refused(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps(RUN) + "\n" + json.dumps({"type": "end"}) + "\n")
    with pytest.raises(ReportFileError, match=re.escape(
            f"{path}: was written by an earlier simreel, whose report lines carry no checksum, so its verdicts cannot "
            "be checked; replay again with --report (--overwrite replaces it)")):
        load_log(path)


def test_two_runs_never_write_one_report(tmp_path):
    path = tmp_path / "r.jsonl"
    with ReportLog(path, resume=False) as log:
        log.write(RUN)
        with pytest.raises(ReportFileError, match="another simreel replay is writing this report"):
            ReportLog(path, resume=False)
        assert len(list(read_log(path))) == 1  # the refused run did not truncate it


def test_the_document_has_each_episode_once_and_the_verdicts_read_back(tmp_path):
    path = tmp_path / "r.jsonl"
    _log(path, ("/d/a.h5", 0, "exact"), ("/d/b.h5", 0, "diverged"), ("/d/a.h5", 0, "diverged"))
    tally = write_report(path, tmp_path / "r.json")
    doc = json.loads((tmp_path / "r.json").read_text())
    assert [(e["file"], e["index"], e["verdict"]) for e in doc["episodes"]] == [
        ("/d/a.h5", 0, "exact"), ("/d/b.h5", 0, "diverged")]  # the retried episode counts once: the first line
    assert doc["complete"] is False and doc["totals"]["diverged"] == 1 == tally.count("diverged")
    assert [f["path"] for f in doc["files"]] == ["/d/a.h5", "/d/b.h5"]
    from_lines = read_verdicts(tmp_path / "r.json")
    path.unlink()
    from_document = read_verdicts(tmp_path / "r.json")
    assert from_lines == from_document
    assert from_lines.verdicts == {("/d/a.h5", 0): "exact", ("/d/b.h5", 0): "diverged"}
    assert from_lines.files == {"/d/a.h5": (1, 2), "/d/b.h5": (1, 2)}
