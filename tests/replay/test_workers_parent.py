"""A pool's worker processes end with the process that started them, however early it dies (real processes)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from tests.support.children import child_pids, running, wait_ended
from tests.support.processes import simreel_command


def _started_worker(driver: subprocess.Popen, timeout: float = 120) -> list[int]:
    """The children of `driver` (its pool's worker and multiprocessing's resource tracker) as soon as its worker
    process exists: a worker then still starting (importing), long before its initializer runs."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        children = child_pids(driver.pid)
        if any(b"spawn_main" in _cmdline(pid) for pid in children):
            return children
        assert driver.poll() is None, f"the replay ended with {driver.returncode} before starting a worker"
        time.sleep(0.01)
    raise AssertionError(f"no worker process started in {timeout} s")


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def test_a_worker_whose_driver_was_killed_while_it_started_ends(record):
    path = record("PickCube-v1", 2, 5, "--env-kwargs", '{"reconfiguration_freq": 1}')  # two chains: a pool starts
    driver = subprocess.Popen(simreel_command("replay", str(path), "--workers", "2", "-q"),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    children: list[int] = []
    try:
        children = _started_worker(driver)
        time.sleep(0.2)  # the driver has handed the worker what it needs to start; the worker is importing
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait()
        # before the fix, the worker took init (pid 1) for its parent and waited forever on the pool's queue
        wait_ended(children, timeout=10)
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait()
        for pid in children:
            if running(pid):
                os.kill(pid, signal.SIGKILL)
