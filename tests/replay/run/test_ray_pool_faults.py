"""`simreel replay --ray` meeting a cluster that is not what it asked for: fewer CPUs than `--workers` (the actors
are capped, with a note, instead of waiting for ever), an address where nothing listens (one line within seconds),
a cluster already running on this machine (plain `--ray` starts its own beside it), and SIGTERM (simreel's line,
exit 143 and the resume hint, not Ray's dumps)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from support.processes import free_port, stop_ray_node

pytest.importorskip("ray", reason="Ray is the optional extra simreel[ray] (make test installs it)")

RAY = Path(sys.executable).with_name("ray")


def _replay(*args: str, env: dict[str, str] | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simreel", "replay", *args, "-q"], capture_output=True, text=True,
                          timeout=timeout, env=env)


def test_more_workers_than_the_cluster_has_cpus_are_capped_with_a_note(record):
    cpus = os.cpu_count() or 1
    done = _replay(str(record("PickCube-v1", 2, 8)), "--ray", "--workers", str(cpus + 1))
    assert done.returncode == 0, done.stderr
    found = re.search(rf"note: --workers {cpus + 1}: the Ray cluster has (\d+) CPU\(s\), one per worker, so (\d+) "
                      r"worker\(s\) replayed", done.stdout)
    assert found and found.group(1) == found.group(2) and int(found.group(1)) <= cpus, done.stdout
    assert "2 of 2 episode(s) verified" in done.stdout


def test_an_address_where_nothing_listens_is_one_line_within_seconds(record):
    address = f"127.0.0.1:{free_port()}"
    start = time.monotonic()
    done = _replay(str(record("PickCube-v1", 2, 8)), "--ray", address, timeout=120)
    assert done.returncode == 2
    assert time.monotonic() - start < 30
    assert done.stderr.startswith(f"simreel replay: error: --ray {address}: no Ray cluster answers there (")
    assert done.stderr.count("\n") == 1, done.stderr


@pytest.fixture
def running_cluster():
    """`ray start --head` on this machine, found where plain `ray.init()` looks (RAY_TMPDIR's address file)."""
    temp_dir = tempfile.mkdtemp(prefix="sr_rc_", dir="/tmp")  # short: Ray's socket paths have a length limit
    env = {**os.environ, "RAY_TMPDIR": temp_dir}
    head = subprocess.Popen([str(RAY), "start", "--head", "--block", "--num-cpus", "1", "--disable-usage-stats",
                             "--port", str(free_port()), "--include-dashboard", "false",
                             "--object-store-memory", str(128 * 1024**2)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True, env=env)
    try:
        deadline = time.monotonic() + 120
        while not (Path(temp_dir) / "ray" / "ray_current_cluster").exists():
            assert head.poll() is None and time.monotonic() < deadline, "ray start --head did not come up"
            time.sleep(0.5)
        yield env
    finally:
        stop_ray_node(head)


def test_plain_ray_starts_its_own_instance_beside_a_running_cluster(record, running_cluster):
    done = _replay(str(record("PickCube-v1", 2, 8)), "--ray", env=running_cluster)
    assert done.returncode == 0, done.stderr
    assert "2 of 2 episode(s) verified (2 exact, 0 within tolerance); all verified" in done.stdout


def _episode_lines(log: Path) -> int:
    return log.read_text().count('"type":"episode"') if log.exists() else 0


def test_sigterm_of_a_ray_run_is_simreels_stop_with_the_resume_hint(record, tmp_path):
    report = tmp_path / "r.json"
    proc = subprocess.Popen([sys.executable, "-m", "simreel", "replay", str(record("PickCube-v1", 12, 30)), "--ray",
                             "--report", str(report), "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 300
    while _episode_lines(tmp_path / "r.jsonl") < 1:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "SIGTERM received" not in err and "Traceback" not in err, err
    last = err.splitlines()[-1]
    assert last.startswith("simreel replay: terminated (SIGTERM); ") and err.count("simreel replay:") == 1, err
    assert last.endswith(f"finish with: simreel replay --resume {report}"), err
    assert json.loads(report.read_text())["complete"] is False
