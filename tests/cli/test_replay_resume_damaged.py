"""`simreel replay --resume` takes a report's lines as input, and checks every one: a line changed since it was
written (its checksum), a verdict on an episode or a file the run does not replay, a file line planning another
number of episodes, a report of a simreel whose lines carried no checksum — each refuses the resume with one line
naming the line (exit 2), never a verdict."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from simreel.cli.main import main
from simreel.replay.report.log import signed_line


@pytest.fixture
def cut_report(record, tmp_path, capsys) -> tuple[Path, Path]:
    """(recording of 3 episodes, r.json): the lines of its replay as a kill after 2 verdicts leaves them; line 1
    is the run, 2 the file, 3 and 4 the verdicts."""
    path = record("PickCube-v1", 3, 5)
    report = tmp_path / "r.json"
    assert main(["replay", str(path), "--report", str(report), "-q"]) == 0
    log = tmp_path / "r.jsonl"
    log.write_text("".join(log.read_text().splitlines(keepends=True)[:4]))
    report.unlink()
    capsys.readouterr()
    return path, report


def _lines(report: Path) -> list[dict]:
    lines = [json.loads(line) for line in report.with_name("r.jsonl").read_text().splitlines()]
    for line in lines:
        del line["crc32"]
    return lines


def _signed_again(report: Path, change: Callable[[list[dict]], None]) -> None:
    """Apply `change` to the report's lines and write each with the checksum of its new text."""
    lines = _lines(report)
    change(lines)
    report.with_name("r.jsonl").write_bytes(b"".join(signed_line(line) for line in lines))


def _refused(report: Path, capsys) -> str:
    assert main(["replay", "--resume", str(report), "-q"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1
    assert not report.exists()
    return captured.err


def test_a_byte_changed_in_a_verdict_refuses_the_resume(cut_report, capsys):
    """Regression: "diverged" → "divergeX" (or "error" → "exact") was resumed into "all verified", exit 0."""
    _, report = cut_report
    log = report.with_name("r.jsonl")
    log.write_bytes(log.read_bytes().replace(b'"verdict":"exact"', b'"verdict":"exacX"', 1))
    assert _refused(report, capsys) == (
        f"simreel replay: error: {log}: line 3 is damaged (its checksum does not match its text: it changed since it "
        "was written), so no verdict of the report can be trusted; replay again with --report (--overwrite replaces "
        "it)\n")


def _extra_episode(lines: list[dict]) -> None:
    lines.append({**lines[3], "index": 7})


def _other_file(lines: list[dict]) -> None:
    lines.append({**lines[3], "file": "/elsewhere/other.h5"})


def _more_planned(lines: list[dict]) -> None:
    lines[1]["episodes"] = 4


def _unknown_verdict(lines: list[dict]) -> None:
    lines[3]["verdict"] = "divergeX"


@pytest.mark.parametrize(("change", "problem"), [
    (_extra_episode, "line 5 gives a verdict on episode 7 of {path}, which the run does not replay"),
    (_other_file, "line 5 gives a verdict on /elsewhere/other.h5, which no line before it lists as a file of the run"),
    (_more_planned, "line 2 plans 4 episode(s) of {path}, and the run replays 3"),
    (_unknown_verdict, 'line 4 gives the verdict "divergeX", which is none of exact, within_tolerance, diverged, '
                       "error"),
], ids=["no-such-episode", "no-such-file", "more-planned", "unknown-verdict"])
def test_a_signed_line_the_run_cannot_have_written_refuses_the_resume(cut_report, capsys, change, problem):
    """Regression: such lines were counted ("4 of 4 verified" with 3 planned)."""
    path, report = cut_report
    _signed_again(report, change)
    err = _refused(report, capsys)
    assert err.startswith(f"simreel replay: error: {report.with_name('r.jsonl')}: "
                          f"{problem.format(path=path.resolve())}"), err


def test_a_report_without_checksums_is_refused_with_what_to_do(cut_report, capsys):
    _, report = cut_report
    log = report.with_name("r.jsonl")
    log.write_text("".join(json.dumps(line) + "\n" for line in _lines(report)))
    assert _refused(report, capsys) == (
        f"simreel replay: error: {log}: was written by an earlier simreel, whose report lines carry no checksum, so "
        "its verdicts cannot be checked; replay again with --report (--overwrite replaces it)\n")


def test_the_lines_as_written_resume(cut_report, capsys):
    _, report = cut_report
    _signed_again(report, lambda lines: None)
    assert main(["replay", "--resume", str(report), "-q"]) == 0
    assert "3 of 3 episode(s) verified (3 exact, 0 within tolerance); all verified" in capsys.readouterr().out
