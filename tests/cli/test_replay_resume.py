"""`simreel replay --resume` finishes exactly the run its report began: the recordings its file lines list (not
those added to a folder since), none vanished or changed, with the `--import`s of that run found where it found them
(from another working folder too). A run that cannot go on — a bad `--import`, a worker process killed, a full
disk — says so in one line (exit 2), keeps the verdicts it reached and says how to finish."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.small_disk import fill, small_disk

from simreel.cli.main import main
from simreel.replay.report.log import signed_line


@pytest.fixture
def folder(record, tmp_path) -> Path:
    """data/: two recordings of two 8-step episodes each."""
    data = tmp_path / "data"
    data.mkdir()
    shutil.copy(record("PickCube-v1", 2, 8), data / "a.h5")
    shutil.copy(record("PickCube-v1", 2, 8, "--seed", "5"), data / "b.h5")
    return data


def _cut(report: Path, keep_episodes: int) -> None:
    """Make `report`'s lines those of a run killed after `keep_episodes` verdicts (its document not written)."""
    log = report.with_name(report.name + "l")
    lines, episodes = [], 0
    for line in log.read_text().splitlines(keepends=True):
        kind = json.loads(line)["type"]
        if kind == "end" or (kind == "episode" and episodes == keep_episodes):
            break
        episodes += kind == "episode"
        lines.append(line)
    log.write_text("".join(lines))
    report.unlink()


def _interrupted_run(folder: Path, report: Path, capsys, *extra: str) -> None:
    assert main(["replay", str(folder), "--report", str(report), "-q", *extra]) == 0
    capsys.readouterr()
    _cut(report, 2)


def test_resume_replays_the_runs_own_recordings_not_those_added_since(folder, record, tmp_path, capsys):
    report = tmp_path / "r.json"
    _interrupted_run(folder, report, capsys)
    shutil.copy(record("PickCube-v1", 1, 6), folder / "new.h5")
    assert main(["replay", "--resume", str(report), "-q"]) == 0
    out = capsys.readouterr().out
    assert "4 of 4 episode(s) verified (4 exact, 0 within tolerance); all verified" in out
    assert "new.h5" not in out
    doc = json.loads(report.read_text())
    assert [Path(f["path"]).name for f in doc["files"]] == ["a.h5", "b.h5"] and doc["complete"] is True


def test_a_recording_gone_since_the_report_began_refuses_the_resume(folder, tmp_path, capsys):
    report = tmp_path / "r.json"
    _interrupted_run(folder, report, capsys)
    (folder / "b.h5").unlink()
    assert main(["replay", "--resume", str(report), "-q"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == (f"simreel replay: error: {folder / 'b.h5'} is gone since {report} began: its episodes "
                            "cannot be replayed; put it back to resume, or start a new report (--overwrite)\n")


def _as_an_older_report(report: Path) -> None:
    """Make the run line name its --import files as given, relative to its folder (simreel kept them so before),
    with the checksum of its new text."""
    log = report.with_name(report.name + "l")
    first, rest = log.read_text().split("\n", 1)
    run = json.loads(first)
    del run["crc32"]
    run["options"]["imports"] = [os.path.relpath(spec, run["cwd"]) for spec in run["options"]["imports"]]
    log.write_bytes(signed_line(run) + rest.encode())


@pytest.mark.parametrize("older", [False, True], ids=["kept-absolute", "older-report-relative"])
def test_resume_from_another_folder_imports_what_the_run_imported(folder, tmp_path, capsys, monkeypatch, older):
    (tmp_path / "noop.py").write_text("LOADED = True\n")
    monkeypatch.chdir(tmp_path)
    report = tmp_path / "r.json"
    _interrupted_run(folder, report, capsys, "--import", "noop.py")
    run = json.loads(report.with_name("r.jsonl").read_text().split("\n", 1)[0])
    assert run["options"]["imports"] == [str(tmp_path / "noop.py")]
    if older:
        _as_an_older_report(report)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(["replay", "--resume", str(report), "-q", "--trust-recorded-imports"]) == 0, capsys.readouterr()
    doc = json.loads(report.read_text())
    assert doc["ok"] is True and {e["verdict"] for e in doc["episodes"]} == {"exact"}


def test_an_import_that_cannot_be_loaded_is_one_line_before_any_episode(folder, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["replay", str(folder), "--import", "nothere.py", "-q"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == f"simreel replay: error: --import {tmp_path / 'nothere.py'}: file not found\n"


def _replay(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "simreel", "replay", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _episode_lines(log: Path) -> int:
    """Whole episode lines of `log` (not one a stopped write cut short)."""
    lines = log.read_text().splitlines(keepends=True) if log.exists() else []
    return sum(line.endswith("\n") and '"type":"episode"' in line for line in lines)


def _pool_workers(pid: int) -> list[int]:
    """The pool's worker processes of `pid` (not multiprocessing's resource tracker)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            parent = int((cmdline.parent / "stat").read_text().rsplit(")", 1)[1].split()[1])
            text = cmdline.read_bytes().decode(errors="replace")
        except (OSError, IndexError, ValueError):
            continue
        if parent == pid and "spawn_main" in text:
            found.append(int(cmdline.parent.name))
    return found


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the pool's processes through /proc")
def test_a_pool_worker_killed_ends_the_run_with_one_line_and_resume_finishes(record, tmp_path):
    report = tmp_path / "r.json"
    own_scenes = ("--env-kwargs", '{"reconfiguration_freq": 1}')  # each episode a chain: two processes replay
    proc = _replay(str(record("PickCube-v1", 12, 20, *own_scenes)), "--report", str(report), "--workers", "2", "-q")
    deadline = time.monotonic() + 300
    while _episode_lines(tmp_path / "r.jsonl") < 2:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.1)
    (worker,) = _pool_workers(proc.pid)
    os.kill(worker, 9)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert err.count("\n") == 1 and err.startswith("simreel replay: error: a worker process was killed by SIGKILL (out "
                                                   "of memory? a kill -9?); the pool was replaying episode(s) ")
    assert err.endswith(f"finish with: simreel replay --resume {report} (with fewer --workers if memory ran out)\n")
    doc = json.loads(report.read_text())
    assert doc["complete"] is False and len(doc["episodes"]) >= 2
    done = subprocess.run([sys.executable, "-m", "simreel", "replay", "--resume", str(report), "-q"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert json.loads(report.read_text())["complete"] is True


def test_a_full_disk_under_the_report_is_one_line_saying_what_was_kept(record, tmp_path, capsys):
    path = record("PickCube-v1", 16, 5)
    capsys.readouterr()
    with small_disk(tmp_path, 256) as disk:
        report = disk / "r.json"
        fill(disk, 6)
        assert main(["replay", str(path), "--report", str(report), "-q"]) == 2
        captured = capsys.readouterr()
        kept = _episode_lines(disk / "r.jsonl")
        assert 0 < kept < 16
        assert captured.out == ""
        assert captured.err == (f"simreel replay: error: {disk / 'r.jsonl'}: the disk is full: it keeps every "
                                f"verdict reached before ({kept} this run; the line cut short is dropped when the run "
                                "is resumed); free some space or write to another disk, then finish with: simreel "
                                f"replay --resume {report}\n")
        for filler in disk.glob("filler*"):
            filler.unlink()
        assert main(["replay", "--resume", str(report), "-q"]) == 0
        assert f"resumed {report}: {kept} episode(s) already had their verdict" in capsys.readouterr().out
        assert json.loads(report.read_text())["complete"] is True
