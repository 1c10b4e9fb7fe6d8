"""The `simreel` executable and its standard streams, in real processes: started with some of them closed (a script's
`<&- >&- 2>&-`, a daemon), it runs as with /dev/null there and keeps its exit status."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from simreel.formats import open_reader


def _simreel_closing(streams: str, *argv: str) -> subprocess.CompletedProcess:
    """`python -m simreel ARGV` started with the descriptors of `streams` (a shell redirection such as ``<&- >&-``)
    closed."""
    return subprocess.run(["sh", "-c", f'exec "$@" {streams}', "sh", sys.executable, "-m", "simreel", *argv],
                          capture_output=True, text=True, timeout=120)


def test_a_recording_started_without_stdin_stdout_and_stderr_is_written_whole(tmp_path):
    """Regression: the writer child's pipes took descriptors 0 and 1 and were replaced by its own /dev/null
    stdin/stdout ("the writer process ended", no file), and with stderr closed its first line raised (exit 1)."""
    out = tmp_path / "r.h5"
    done = _simreel_closing("<&- >&- 2>&-", "record", "PickCube-v1", "-o", str(out), "-n", "2", "--max-steps", "3",
                            "--render-backend", "none", "-q")
    assert done.returncode == 0
    with open_reader(out) as reader:
        assert [ep.length for ep in reader.episodes] == [3, 3]


def test_an_error_without_stderr_is_still_exit_2(tmp_path: Path):
    done = _simreel_closing("2>&-", "inspect", str(tmp_path / "missing.h5"))
    assert (done.returncode, done.stdout) == (2, "")
