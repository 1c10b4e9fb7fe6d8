"""A run's streaming report (`simreel.replay.report.log`): lines flushed as they come, a line cut by a kill is
dropped (never misread), a damaged line is named, two runs never write one report, and the report document and
the verdicts are read back from the lines."""

from __future__ import annotations

import json

import pytest

from simreel.errors import ReportFileError, UsageError
from simreel.replay.report.log import (
    ReportLog,
    load_log,
    read_log,
    read_verdicts,
    report_paths,
    write_report,
)
from simreel.replay.report.report import EpisodeReport
from simreel.replay.report.tally import FileTally

RUN = {"type": "run", "options": {"mode": "actions", "resync": None}, "tolerances": {"pos": 1e-5}}


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
    assert load_log(path).done == {("/d/a.h5", 0), ("/d/a.h5", 1)}
    with ReportLog(path, resume=True) as log:
        log.episode("/d/a.h5", _episode(2), warnings=[])
    assert path.read_text().startswith(whole) and len(list(read_log(path))) == 5


def test_a_damaged_line_is_named(tmp_path):
    path = tmp_path / "r.jsonl"
    _log(path, ("/d/a.h5", 0, "exact"))
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join([lines[0], "{not json\n", *lines[1:]]))
    with pytest.raises(ReportFileError, match="line 2 is not JSON"):
        load_log(path)
    path.write_text('{"type": "episode", "file": "x", "index": 0}\n')
    with pytest.raises(ReportFileError, match="does not start with a run line"):
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
