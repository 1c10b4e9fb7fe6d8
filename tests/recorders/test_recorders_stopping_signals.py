"""`simreel.recorders.stopping_signals`: a Python script's recording stopped by SIGTERM is closed as Ctrl-C closes it,
the episode it cut short committed with its note, in a real process sent a real signal."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

from support.children import child_pids, wait_ended
from support.processes import read_line

from simreel.formats import open_reader

SCRIPT = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from simreel.errors import Terminated
    from simreel.recorders import RecordWrapper, stopping_signals
    from simreel.sim.make import make_env

    zero = np.zeros(8, np.float32)
    try:
        with stopping_signals(), RecordWrapper(make_env("PickCube-v1"), sys.argv[1]) as env:
            for seed in range(3):
                env.reset(seed=seed)
                for _ in range(3 if seed < 2 else 2):
                    env.step(zero)
            print("running", flush=True)
            time.sleep(120)  # mid-episode: SIGTERM comes here
    except Terminated:
        sys.exit(143)
    """
)


def test_sigterm_under_stopping_signals_commits_the_cut_episode_and_closes_the_file(tmp_path):
    """With Python's default SIGTERM handler the process died on the spot: an MCAP file without its footer (needing
    `simreel recover`) and the running episode lost."""
    out = tmp_path / "r.mcap"
    process = subprocess.Popen([sys.executable, "-c", SCRIPT, str(out)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert read_line(process, timeout=180) == "running"
        writers = child_pids(process.pid)
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=60) == 143, process.stderr.read()[-2000:]
        wait_ended(writers)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    with open_reader(out) as r:  # a whole MCAP file: no recover needed
        assert [(m.seed, m.length, m.notes) for m in r.episodes] == [
            (0, 3, []), (1, 3, []),
            (2, 2, ["cut short: SIGTERM stopped the recording before this episode ended"])]
