"""Ctrl-C and SIGTERM at the moments a signal sweep found wrong: while mani_skill imports (its libraries swallowed the
signal or crashed on it) and while the CLI starts. Each run is a real `simreel` process; the signal is sent the moment
a given module starts importing, so the moment is exact."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

from simreel.cli.main import main

_SIGNAL_AT_IMPORT = textwrap.dedent("""
    import os, signal, sys

    target, signum = sys.argv[1], getattr(signal, sys.argv[2])

    class SignalAtImport:  # sends the signal as `target` starts importing (it then imports as usual)
        fired = False

        def find_spec(self, name, path=None, target_module=None):
            if name == target and not SignalAtImport.fired:
                SignalAtImport.fired = True
                os.kill(os.getpid(), signum)
            return None

    sys.meta_path.insert(0, SignalAtImport())
    sys.argv = ["simreel", *sys.argv[3:]]
    from simreel.cli.main import main
    sys.exit(main())
""")


def _simreel_signalled_at_import(module: str, signum: str, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _SIGNAL_AT_IMPORT, module, signum, *argv], capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize(("module", "signum", "status", "line"), [
    ("scipy.spatial", "SIGTERM", 143, "simreel audit: terminated (SIGTERM)"),  # trimesh swallowed it: exit 0
    ("trimesh.path.path", "SIGINT", 130, "simreel audit: interrupted"),  # a half-made trimesh class: exit 3
], ids=["swallowed", "half-imported"])
def test_a_signal_while_mani_skill_imports_stops_the_command(tmp_path, module, signum, status, line):
    """trimesh (which mani_skill imports) catches every exception around its optional imports: a Ctrl-C landing there
    was swallowed (the audit ran on and exited 0) or left a stand-in class behind that failed later (exit 3, an
    "internal error"); inside torch's or sapien's native initialisation it aborted the process or became an
    ImportError. The import now runs whole, and the signal stops the command right after it."""
    report = tmp_path / "audit.json"
    done = _simreel_signalled_at_import(module, signum, "audit", "PickCube-v1", "--steps", "2", "-q",
                                        "--json", str(report))
    assert (done.returncode, done.stderr.splitlines()) == (status, [line])
    assert not report.exists()


def test_a_signal_while_the_cli_starts_is_its_one_line():
    """A Ctrl-C as the CLI builds its parser (importing each command's module) printed Python's traceback."""
    done = _simreel_signalled_at_import("simreel.cli.replay", "SIGINT", "inspect", "no-such-file.h5")
    assert (done.returncode, done.stderr.splitlines()) == (130, ["simreel: interrupted"])


def test_an_error_after_a_swallowed_signal_is_that_signal_not_an_internal_error(monkeypatch, capsys):
    """A library that swallows a KeyboardInterrupt can leave something half made, which fails later: the command was
    interrupted, not broken (exit 130, not 3)."""
    import simreel.cli.inspect as inspect_cmd

    def swallowing(args):
        try:
            signal.raise_signal(signal.SIGINT)
        except BaseException:  # noqa: BLE001 - what trimesh does around its optional imports
            pass
        raise TypeError("unsupported operand type(s) for |: 'ExceptionWrapper' and 'NoneType'")

    monkeypatch.setattr(inspect_cmd, "run", swallowing)
    assert main(["inspect", "whatever.h5"]) == 130
    assert capsys.readouterr().err.splitlines() == ["simreel inspect: interrupted"]


def test_a_bug_while_a_commit_held_a_ctrl_c_is_still_an_internal_error(monkeypatch, capsys):
    """The signal a failing block held is noted, not raised: its error wins (exit 3 for a bug, not 130)."""
    import simreel.cli.inspect as inspect_cmd
    from simreel.io.durable import deferred_signals

    def failing_commit(args):
        with deferred_signals():
            signal.raise_signal(signal.SIGINT)
            raise RuntimeError("boom")

    monkeypatch.setattr(inspect_cmd, "run", failing_commit)
    assert main(["inspect", "whatever.h5"]) == 3
    assert capsys.readouterr().err.splitlines()[-1].startswith("simreel inspect: internal error: RuntimeError: boom")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_once_the_command_has_finished_changes_nothing(tmp_path, signum):
    """Regression: the interpreter takes ~0.6 s to exit after a command that imported torch, and a Ctrl-C then killed
    the process (exit 130 with no line, or Python's KeyboardInterrupt traceback from its shutdown) although the
    recording was complete and said so. The executable (`run`, as `python -m simreel` and the console script) ignores
    the signals once the command has returned: it exits with the command's status."""
    import importlib.metadata
    import time

    [script] = [e for e in importlib.metadata.entry_points(group="console_scripts") if e.name == "simreel"]
    assert script.value == "simreel.cli.main:run"  # the `simreel` executable exits as `python -m simreel` does
    out = tmp_path / "r.h5"
    process = subprocess.Popen([sys.executable, "-m", "simreel", "record", "PickCube-v1", "-o", str(out), "-n", "1",
                                "--max-steps", "3", "--render-backend", "none", "-q"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = iter(process.stdout.readline, "")
    summary = next(line for line in lines if line.startswith("recorded "))
    time.sleep(0.1)  # the command has returned: the interpreter is shutting down
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=120)
    assert (process.returncode, stderr) == (0, ""), summary
