"""Real recording processes for the fault tests: start one, wait until it has committed some episodes, signal it."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

SUPPORT = Path(__file__).parent


def simreel(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """`simreel ARGS` in its own process, its output captured as text."""
    return subprocess.run([sys.executable, "-m", "simreel", *args], capture_output=True, text=True, timeout=timeout)


def child_pids(pid: int) -> list[int]:
    """The processes `pid` started that are still running (a recorder's writer process, `simreel.formats.
    writer_process`)."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            found += [int(p) for p in (task / "children").read_text().split()]
        except OSError:  # the thread ended meanwhile
            continue
    return found


def wait_ended(pids: list[int], timeout: float = 30) -> None:
    """Wait until every process of `pids` has ended (a zombie nobody reaps counts as ended); AssertionError if one
    is still running after `timeout` seconds: a writer process must not outlive its recorder."""
    deadline = time.monotonic() + timeout
    for pid in pids:
        while running(pid):
            assert time.monotonic() < deadline, f"process {pid} still runs {timeout} s after its recorder ended"
            time.sleep(0.01)


def running(pid: int) -> bool:
    """True until every thread of `pid` has ended. A process leader shows as a zombie as soon as its own thread
    exits, while its other threads may still be ending and still hold its open files (and their locks)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        threads = [task.name for task in Path(f"/proc/{pid}/task").iterdir()]
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[0] != "Z" or threads != [str(pid)]


class RecordingChild:
    """`record_child.py` (or `simreel` itself, with `cli=True`) running in its own process."""

    def __init__(self, *args: str, cli: bool = False, env: dict[str, str] | None = None) -> None:
        command = [sys.executable, "-m", "simreel", *args] if cli else [sys.executable, str(SUPPORT / "record_child.py"),
                                                                          *args]
        self.proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        self.committed = 0
        self.lines: list[str] = []
        self._pending = b""
        self.stderr = ""

    def wait_committed(self, n: int, timeout: float = 180) -> int:
        """Wait until the child says it has committed at least `n` episodes; returns how many it has."""
        deadline = time.monotonic() + timeout
        fd = self.proc.stdout.fileno()
        while self.committed < n:
            left = deadline - time.monotonic()
            assert left > 0, f"the child committed {self.committed} of {n} episodes in {timeout} s"
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                continue
            data = os.read(fd, 65536)
            if not data:
                self.proc.wait()
                raise AssertionError(f"the recording child ended: {self.proc.stderr.read().decode()[-2000:]}")
            *lines, self._pending = (self._pending + data).split(b"\n")
            self._note([x.decode().strip() for x in lines])
        return self.committed

    def _note(self, lines: list[str]) -> None:
        """Keep the child's `lines`, and the count of episodes its last "committed N" line says."""
        for line in lines:
            self.lines.append(line)
            if line.startswith("committed "):
                self.committed = int(line.split()[1])

    def signal(self, sig: int = signal.SIGKILL, timeout: float = 120) -> int:
        """Send `sig` to the recording process (not to its writer process), wait for the end of both; returns the
        recording process's exit status (negative: killed by that signal)."""
        writers = child_pids(self.proc.pid)
        os.kill(self.proc.pid, sig)
        status = self.wait(timeout)
        wait_ended(writers)
        return status

    def wait(self, timeout: float = 300) -> int:
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise
        self._note([line.strip() for line in (self._pending + out).decode().splitlines()])
        self.stderr = err.decode()
        return self.proc.returncode

    def __enter__(self) -> RecordingChild:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def started_pool_worker(driver: subprocess.Popen, timeout: float = 120) -> list[int]:
    """The children of `driver` (its pool's worker and multiprocessing's resource tracker) as soon as its worker
    process exists: a worker then still starting (importing), long before its initializer runs."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        children = child_pids(driver.pid)
        if pool_workers(children):
            return children
        assert driver.poll() is None, f"the run ended with {driver.returncode} before starting a worker"
        time.sleep(0.01)
    raise AssertionError(f"no worker process started in {timeout} s")


def pool_workers(pids: list[int]) -> list[int]:
    """The pool's worker processes among `pids` (started by multiprocessing's ``spawn``), not its resource tracker."""
    return [pid for pid in pids if b"spawn_main" in _cmdline(pid)]


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def kill_all(driver: subprocess.Popen, pids: list[int]) -> None:
    """Kill `driver` and the processes `pids` it started, those still running: what a failed test leaves behind."""
    if driver.poll() is None:
        driver.kill()
        driver.wait()
    for pid in pids:
        if running(pid):
            os.kill(pid, signal.SIGKILL)
