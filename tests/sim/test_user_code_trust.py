"""Task code that came with a recording, or with a report, runs only with the user's word: every command that
rebuilds a recording's env refuses, in one line (exit 2), to import what the recording names, until the user
gives ``--import``, ``--trust-recorded-imports`` or ``SIMREEL_TRUST_RECORDED_IMPORTS=1``."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from support.processes import simreel_command

from simreel.cli.main import main

MARKER_TASKS = "import pathlib\npathlib.Path(__file__).with_suffix('.ran').touch()\n"
"""Task code that leaves a file beside itself when it is imported: what a planted file could do, harmlessly."""

REFUSED = ("{path}: the recording asks to import {spec}, code that came with the data and would run as you; pass "
           "--import with the task code you trust (e.g. --import {spec}), or --trust-recorded-imports (or "
           "SIMREEL_TRUST_RECORDED_IMPORTS=1) if you trust where it came from")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """ds/pick.h5, recorded with --import src/planted_tasks.py, which is gone since; ds/planted_tasks.py planted beside it."""
    root = tmp_path_factory.mktemp("imports")
    (root / "src").mkdir()
    (root / "ds").mkdir()
    (root / "elsewhere").mkdir()
    tasks = root / "src" / "planted_tasks.py"
    tasks.write_text(MARKER_TASKS)
    assert main(["record", "PickCube-v1", "-o", str(root / "ds" / "pick.h5"), "-n", "1", "--max-steps", "4",
                 "--seed", "0", "--no-poses", "--render-backend", "none", "--import", str(tasks), "-q"]) == 0
    tasks.unlink()
    (root / "ds" / "planted_tasks.py").write_text(MARKER_TASKS)
    return root


def _run(dataset: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(simreel_command(*args), capture_output=True, text=True, timeout=300,
                          cwd=dataset / "elsewhere", env={**os.environ, **env})


def test_a_file_planted_beside_a_recording_does_not_run_on_replay(dataset):
    """It did: with the recorded file gone, `simreel replay` imported the planted_tasks.py found beside the recording
    (exit 0, only a "task code hash changed" note)."""
    recording, planted = dataset / "ds" / "pick.h5", dataset / "ds" / "planted_tasks.ran"
    refused = _run(dataset, "replay", "../ds/pick.h5", "-q")
    spec = str(dataset / "src" / "planted_tasks.py")
    assert (refused.returncode, refused.stderr) == (
        2, "simreel replay: error: " + REFUSED.format(path=recording, spec=spec) + "\n")
    assert not planted.exists()
    trusted = _run(dataset, "replay", "../ds/pick.h5", "-q", "--trust-recorded-imports")
    assert trusted.returncode == 0, trusted.stderr
    assert planted.exists()  # trusted: found beside the recording, as documented
    planted.unlink()
    assert not recording.with_suffix(".ran").exists()


@pytest.mark.parametrize("command", [
    ["view", "{rec}", "--save", "{out}/s.rrd"],
    ["video", "{rec}", "-o", "{out}"],
    ["audit", "--trajectory", "{rec}"],
    ["convert", "{rec}", "{out}/p.mcap", "--poses"],
    ["convert", "{rec}", "{out}/c.h5", "--obs-mode", "state"],
    ["replay", "{rec}", "--workers", "2"],
], ids=["view", "video", "audit", "convert-poses", "convert-obs", "replay-workers"])
def test_every_command_that_rebuilds_the_env_refuses_in_one_line(dataset, tmp_path, capsys, monkeypatch, command):
    monkeypatch.delenv("SIMREEL_TRUST_RECORDED_IMPORTS", raising=False)
    rec = dataset / "ds" / "pick.h5"
    args = [a.format(rec=rec, out=tmp_path) for a in command]
    assert main([*args, "-q"] if command[0] in ("replay", "video", "convert", "audit") else args) == 2
    err = capsys.readouterr().err
    assert err == f"simreel {command[0]}: error: " + REFUSED.format(path=rec, spec=dataset / "src" / "planted_tasks.py") + "\n"
    assert not (dataset / "ds" / "planted_tasks.ran").exists()
    assert list(tmp_path.iterdir()) == []


def test_a_resumed_report_imports_its_code_only_with_the_users_word(dataset, tmp_path, capsys, monkeypatch):
    """A report is an input too: its run's --import was imported by `replay --resume` without a word."""
    monkeypatch.delenv("SIMREEL_TRUST_RECORDED_IMPORTS", raising=False)
    rec, tasks = dataset / "ds" / "pick.h5", tmp_path / "own_tasks.py"
    tasks.write_text("")
    report = tmp_path / "r.json"
    assert main(["replay", str(rec), "--import", str(tasks), "--report", str(report), "-q"]) == 0
    capsys.readouterr()
    assert main(["replay", "--resume", str(report), "-q"]) == 2
    assert capsys.readouterr().err == (
        f"simreel replay: error: {report}: the report asks to import {tasks}, code that came with the data and would "
        f"run as you; pass --import with the task code you trust (e.g. --import {tasks}), or "
        "--trust-recorded-imports (or SIMREEL_TRUST_RECORDED_IMPORTS=1) if you trust where it came from\n")
    assert main(["replay", "--resume", str(report), "--trust-recorded-imports", "-q"]) == 0


def test_an_installed_module_a_recording_names_is_imported_without_asking(dataset, tmp_path):
    """simreel.tasks is installed with simreel: naming it asks for nothing a user has not installed."""
    rec = tmp_path / "lift.h5"
    assert main(["record", "SimreelLiftCube-v1", "--import", "simreel.tasks", "--policy", "scripted", "-o", str(rec),
                 "-n", "1", "--max-steps", "3", "--render-backend", "none", "-q"]) == 0
    shutil.copy(rec, dataset / "elsewhere" / "lift.h5")
    done = _run(dataset, "replay", "lift.h5", "-q")
    assert done.returncode == 0, done.stderr
