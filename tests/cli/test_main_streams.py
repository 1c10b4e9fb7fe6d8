"""The `simreel` executable and its standard streams, in real processes: started with some of them closed (a script's
`<&- >&- 2>&-`, a daemon), it runs as with /dev/null there and keeps its exit status; a full one is bad input."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write

from simreel.formats import open_reader


def _simreel_closing(streams: str, *argv: str) -> subprocess.CompletedProcess:
    """`python -m simreel ARGV` with the shell redirections `streams` (such as ``<&- >&-``, which close stdin and
    stdout)."""
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


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_standard_output_is_bad_input_not_an_internal_error(tmp_path):
    """Regression: `simreel inspect X > /dev/full` was "internal error: OSError: [Errno 28] ... please report it", exit
    3; the storage refusing a write is never simreel's bug (`simreel.io.durable.STORAGE_ERRNOS`)."""
    meta = synthetic_meta()
    rec = write(tmp_path / "r.h5", meta, [synthetic_episode(meta, 0, 3)])
    done = _simreel_closing(">/dev/full", "inspect", str(rec))
    assert (done.returncode, done.stderr) == (2, "simreel inspect: error: writing the output: the disk is full; free "
                                                 "some space or write to another disk\n")
