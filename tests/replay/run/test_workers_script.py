"""What a replay with worker processes says when a worker ends by an error of its own as it starts: a script that
starts the replay outside a main guard (each worker process imports the script again) is told to add one, never
that memory may have run out (real processes)."""

from __future__ import annotations

import subprocess
import sys

GUARD = ("a worker process ended with exit status 1 as it started (its error is printed above; a script that starts a "
         'replay with workers must do so under `if __name__ == "__main__":`, as each worker process imports the script '
         "again)")  # then the episodes the pool held, if it held any yet


def test_a_script_without_a_main_guard_is_told_to_add_one(record, tmp_path):
    path = record("PickCube-v1", 2, 5, "--env-kwargs", '{"reconfiguration_freq": 1}')  # two chains: a pool starts
    script = tmp_path / "replay_all.py"
    script.write_text(f"from simreel.replay import ReplayRun\n\nReplayRun({str(path)!r}, workers=2).execute()\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    # before: "a worker process died (killed from outside: out of memory?); ... (with fewer --workers if memory ran out)"
    assert last.startswith(f"simreel.errors.ReplayError: {GUARD}"), last
    assert "memory" not in last
