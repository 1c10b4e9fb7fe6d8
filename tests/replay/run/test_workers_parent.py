"""A pool's worker processes end with the process that started them, however early it dies (real processes)."""

from __future__ import annotations

import os
import signal
import subprocess
import time

from tests.support.children import kill_all, started_pool_worker, wait_ended
from tests.support.processes import simreel_command


def test_a_worker_whose_driver_was_killed_while_it_started_ends(record):
    path = record("PickCube-v1", 2, 5, "--env-kwargs", '{"reconfiguration_freq": 1}')  # two chains: a pool starts
    driver = subprocess.Popen(simreel_command("replay", str(path), "--workers", "2", "-q"),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    children: list[int] = []
    try:
        children = started_pool_worker(driver)
        time.sleep(0.2)  # the driver has handed the worker what it needs to start; the worker is importing
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait()
        # before the fix, the worker took init (pid 1) for its parent and waited forever on the pool's queue
        wait_ended(children, timeout=10)
    finally:
        kill_all(driver, children)
