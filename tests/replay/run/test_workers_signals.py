"""Ctrl-C and SIGTERM while a replay starts, its pool's worker processes included (real processes): the run stops at
once, with its one line and every verdict it reached, and no worker process outlives it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.support.children import kill_all, pool_workers, started_pool_worker, wait_ended
from tests.support.processes import simreel_command

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds worker processes through /proc")

_API_DRIVER = textwrap.dedent("""
    import sys
    from simreel.replay import ReplayRun
    from simreel.sim.user_code import import_mani_skill

    import_mani_skill()  # already done: the pool's worker is then the only process still importing
    run = ReplayRun([sys.argv[1]], workers=2, report=sys.argv[2])
    print("ready", flush=True)
    try:
        run.execute(lambda item, report: print("verdict", item.index, flush=True))
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(130)
""")

_SIGTERM_AS_A_WORKER_IS_FORKED = textwrap.dedent("""
    import os, signal, sys
    import multiprocessing.util as util

    forked = util.spawnv_passfds

    def signalled(*args):  # SIGTERM right after the worker process is forked, before it is handed its set-up
        pid = forked(*args)
        os.kill(os.getpid(), signal.SIGTERM)
        return pid

    util.spawnv_passfds = signalled
    sys.argv = ["simreel", *sys.argv[1:]]
    from simreel.cli.main import main
    sys.exit(main())
""")


_NOT_BEGUN = "simreel replay: {stop}; {report} was not begun (no episode had its verdict yet): run it again"

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


def _wait_importing_torch(pids: list[int], timeout: float = 120) -> None:
    """Until each process of `pids` has loaded torch's library: it is then in its import of mani_skill (seconds more)."""
    deadline = time.monotonic() + timeout
    for pid in pids:
        while "libtorch_cpu" not in Path(f"/proc/{pid}/maps").read_text():
            assert time.monotonic() < deadline, f"process {pid} loaded no torch in {timeout} s"
            time.sleep(0.01)


def test_ctrl_c_while_a_worker_imports_mani_skill_ends_it_at_once(two_chains, tmp_path):
    """A worker process held the pool's SIGTERM until its import of mani_skill was done (seconds), and the run
    waited for it: the import held every signal, even one whose default ends the process, which no half-made
    module can outlive."""
    report = tmp_path / "r.json"
    driver = subprocess.Popen([sys.executable, "-c", _API_DRIVER, str(two_chains), str(report)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    children: list[int] = []
    try:
        assert driver.stdout.readline() == "ready\n", driver.communicate()
        children = started_pool_worker(driver)
        _wait_importing_torch(pool_workers(children))
        driver.send_signal(signal.SIGINT)
        wait_ended(pool_workers(children), timeout=1.0)  # before the fix: 3.8-4.1 s on 2 shared cores
        out, err = driver.communicate(timeout=60)
        wait_ended(children, timeout=10)
        assert (driver.returncode, out.splitlines()[-1]) == (130, "interrupted"), err
        reached = sorted(int(line.split()[1]) for line in out.splitlines() if line.startswith("verdict"))
        kept = json.loads(report.read_text())["episodes"] if report.exists() else []
        assert sorted(e["index"] for e in kept) == reached
    finally:
        kill_all(driver, children)


def test_ctrl_c_of_the_terminal_while_a_worker_starts_is_the_runs_one_line(two_chains, tmp_path):
    """A terminal's Ctrl-C reaches every process of its group: a worker process still importing, before it ignores
    Ctrl-C, printed a KeyboardInterrupt traceback under the run's lines."""
    report = tmp_path / "r.json"
    driver = subprocess.Popen(simreel_command("replay", str(two_chains), "--workers", "2", "--report", str(report),
                                              "-q"), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True)
    children: list[int] = []
    try:
        children = started_pool_worker(driver)
        time.sleep(0.2)  # the worker process is importing simreel, before its initializer
        os.killpg(driver.pid, signal.SIGINT)
        _, err = driver.communicate(timeout=60)
        assert driver.returncode == 130, err
        assert err.splitlines() == [_NOT_BEGUN.format(stop="interrupted", report=report)]
        wait_ended(children, timeout=10)
    finally:
        kill_all(driver, children)


def test_sigterm_while_a_worker_process_is_forked_is_the_runs_one_line(two_chains, tmp_path):
    """SIGTERM handled between the fork of a worker process and the hand-over of its set-up left that process reading
    a closed pipe (an EOFError traceback), outside the pool that would have ended it."""
    report = tmp_path / "r.json"
    done = subprocess.run([sys.executable, "-c", _SIGTERM_AS_A_WORKER_IS_FORKED, "replay", str(two_chains),
                           "--workers", "2", "--report", str(report), "-q"], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 143, done.stderr
    assert done.stderr.splitlines() == [_NOT_BEGUN.format(stop="terminated (SIGTERM)", report=report)]


def test_a_run_stopped_before_its_report_began_says_to_run_it_again(two_chains, tmp_path):
    """Stopped while it built its env (here as mani_skill starts importing), a run said to finish with `--resume
    REPORT`, which then refused: there was no report."""
    report = tmp_path / "r.json"
    done = subprocess.run([sys.executable, "-c", _SIGTERM_AT_IMPORT, "mani_skill.envs", "replay", str(two_chains),
                           "--report", str(report), "-q"], capture_output=True, text=True, timeout=300)
    assert (done.returncode, done.stderr.splitlines()) == (143, [_NOT_BEGUN.format(stop="terminated (SIGTERM)",
                                                                                    report=report)])
    assert not report.exists() and not report.with_name("r.jsonl").exists()
