"""Ctrl-C and SIGTERM while a replay starts (real processes): the run stops with its one line and every verdict it
reached."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

_NOT_BEGUN = "simreel replay: {report} was not begun (no episode had its verdict yet): run it again"

_SIGTERM_AT_IMPORT = textwrap.dedent("""
    import os, signal, sys

    target = sys.argv[1]

    class SignalAtImport:  # SIGTERM as module `target` starts importing (it then imports as usual)
        def find_spec(self, name, path=None, target_module=None):
            if name == target:
                sys.meta_path.remove(self)
                os.kill(os.getpid(), signal.SIGTERM)
            return None

    sys.meta_path.insert(0, SignalAtImport())
    sys.argv = ["simreel", *sys.argv[2:]]
    from simreel.cli.main import main
    sys.exit(main())
""")


@pytest.fixture(scope="module")
def two_chains(record) -> Path:
    """Two episodes whose resets rebuild the scene: two scene chains, so `--workers 2` starts a worker process."""
    return record("PickCube-v1", 2, 5, "--env-kwargs", '{"reconfiguration_freq": 1}')


def test_a_run_stopped_before_its_report_began_says_to_run_it_again(two_chains, tmp_path):
    """Stopped while it built its env (here as mani_skill starts importing), a run said to finish with `--resume
    REPORT`, which then refused: there was no report."""
    report = tmp_path / "r.json"
    done = subprocess.run([sys.executable, "-c", _SIGTERM_AT_IMPORT, "mani_skill.envs", "replay", str(two_chains),
                           "--report", str(report), "-q"], capture_output=True, text=True, timeout=300)
    assert (done.returncode, done.stderr.splitlines()) == (143, [_NOT_BEGUN.format(report=report),
                                                                 "simreel replay: terminated (SIGTERM)"])
    assert not report.exists() and not report.with_name("r.jsonl").exists()
