"""`simreel replay --ray` on a real Ray cluster started here: a head node and a second worker node (separate
`ray start` processes on localhost). Recordings are verified by actors on both nodes, read in place or sent by
the driver (--ship); an actor killed mid-run has its episodes replayed by another, each verdict exactly once."""

from __future__ import annotations

import json
import os
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest
from support.processes import free_port, stop_ray_node

ray = pytest.importorskip("ray", reason="Ray is the optional extra simreel[ray] (make test installs it)")

RAY = Path(sys.executable).with_name("ray")


def _start(*args: str, env: dict[str, str]) -> subprocess.Popen:
    """A `ray start --block` node: it stops its own processes when it is terminated."""
    return subprocess.Popen([str(RAY), "start", "--block", "--num-cpus", "1", "--disable-usage-stats",
                             "--object-store-memory", str(128 * 1024**2), *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True, env=env)


def _nodes_alive(address: str, count: int, env: dict[str, str], timeout: float = 180) -> None:
    probe = ("import ray, sys; ray.init(address=sys.argv[1], logging_level='ERROR', log_to_driver=False); "
             "print(sum(n['Alive'] for n in ray.nodes()))")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done = subprocess.run([sys.executable, "-c", probe, address], capture_output=True, text=True, timeout=120,
                              env=env)
        if done.returncode == 0 and done.stdout.strip() == str(count):
            return
        time.sleep(2)
    raise AssertionError(f"the Ray cluster at {address} did not come up with {count} nodes")


@dataclass(frozen=True)
class Cluster:
    address: str
    env: dict[str, str]
    """The environment of every process of the cluster, and of a driver joining it: its token (Ray turns token
    authentication on for clusters started where a token exists; this one always has its own)."""
    nodes: tuple[int, ...]
    """The `ray start` processes of its nodes, of which its actors' processes descend."""


@pytest.fixture(scope="module")
def cluster():
    """A two-node cluster on localhost: a head and a worker node, one CPU each."""
    temp_dir = tempfile.mkdtemp(prefix="sr_ray_", dir="/tmp")  # short: Ray's socket paths have a length limit
    token = Path(temp_dir) / "token"
    token.write_text(secrets.token_hex(32))
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token)}
    port = free_port()
    address = f"127.0.0.1:{port}"
    head = _start("--head", "--port", str(port), "--node-ip-address", "127.0.0.1", "--include-dashboard", "false",
                  "--temp-dir", temp_dir, env=env)
    nodes = [head]
    try:
        time.sleep(3)
        nodes.append(_start("--address", address, "--node-ip-address", "127.0.0.1", env=env))
        _nodes_alive(address, 2, env)
        yield Cluster(address, env, tuple(node.pid for node in nodes))
    finally:
        for node in reversed(nodes):
            stop_ray_node(node)


@pytest.fixture(scope="module")
def recordings(record):
    return [record("PickCube-v1", 6, 12), record("PickCube-v1", 4, 10, "--seed", "21")]


def _replay(cluster: Cluster, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "simreel", "replay", *args, "--ray", cluster.address, "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=cluster.env)


def _episode_lines(log: Path) -> list[dict]:
    if not log.exists():
        return []
    return [json.loads(line) for line in log.read_text().splitlines(keepends=True)
            if line.endswith("\n") and '"type":"episode"' in line]


def _replay_until_two_verdicts(cluster: Cluster, report: Path, *paths: Path) -> subprocess.Popen:
    """A run of `paths` on two actors, once two verdicts are in its report: the rest are still replaying."""
    proc = _replay(cluster, *map(str, paths), "--workers", "2", "--report", str(report))
    deadline = time.monotonic() + 300
    while len(_episode_lines(report.with_suffix(".jsonl"))) < 2:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.1)
    return proc


def _each_once(doc: dict, total: int) -> None:
    assert doc["complete"] is True and doc["ok"] is True, doc["totals"]
    pairs = Counter((e["file"], e["index"]) for e in doc["episodes"])
    assert len(pairs) == total and max(pairs.values()) == 1
    assert {e["verdict"] for e in doc["episodes"]} == {"exact"}


@pytest.mark.parametrize("ship", [False, True], ids=["read-in-place", "shipped"])
def test_a_two_node_cluster_verifies_recordings(cluster, recordings, tmp_path, ship):
    report = tmp_path / "r.json"
    proc = _replay(cluster, *map(str, recordings), "--workers", "2", "--report", str(report),
                   *(["--ship"] if ship else []))
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    assert "10 of 10 episode(s) verified (10 exact, 0 within tolerance); all verified" in out
    doc = json.loads(report.read_text())
    _each_once(doc, 10)
    nodes = {e["worker"].split(" node ")[1].split()[0] for e in doc["episodes"]}
    assert len(nodes) == 2, doc["episodes"]  # both nodes replayed
    sent = [e["worker"].endswith("(episode sent by the driver)") for e in doc["episodes"]]
    assert sent == [ship] * 10  # a node that sees the file (here: all) reads it in place, unless --ship


def _parent(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[1])
    except OSError:  # it ended
        return 0


def _actor_pids(cluster: Cluster) -> list[int]:
    """The actor processes of `cluster`'s nodes: not those of another Ray instance on this machine (another test
    file's, running at the same time on another worker)."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            text = cmdline.read_bytes().decode(errors="replace")
        except OSError:
            continue
        if text.startswith("ray::_Actor"):
            pid = ancestor = int(cmdline.parent.name)
            while ancestor > 1 and ancestor not in cluster.nodes:
                ancestor = _parent(ancestor)
            if ancestor in cluster.nodes:
                pids.append(pid)
    return pids


_OWN_SCENES = ("--env-kwargs", '{"reconfiguration_freq": 1}')
"""Every reset rebuilds the scene: each episode is a scene chain of its own, so both actors have episodes to replay
(the episodes of one chain go to one actor: `simreel.replay.run.worklist.chain_groups`)."""


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the actor processes through /proc")
def test_a_worker_killed_mid_run_has_its_episodes_replayed_elsewhere_once(cluster, record, tmp_path):
    path = record("PickCube-v1", 16, 30, *_OWN_SCENES)
    report = tmp_path / "r.json"
    proc = _replay_until_two_verdicts(cluster, report, path)
    actors = _actor_pids(cluster)
    assert len(actors) == 2, actors
    os.kill(actors[0], signal.SIGKILL)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    assert "note: 1 Ray worker(s) died during the run" in out, out
    doc = json.loads(report.read_text())
    _each_once(doc, 16)
    assert doc["notes"] and "replayed again by others" in doc["notes"][0]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the actor processes through /proc")
def test_the_chain_of_a_killed_worker_goes_on_in_one_worker_its_history_replayed_once(cluster, record, tmp_path):
    """Regression: the two episodes a dead actor had in flight went back as two groups, in reverse order, each
    then replaying the chain's history again (as did the rest of its chain after them)."""
    paths = [record("PickCube-v1", 8, 30), record("PickCube-v1", 8, 30, "--seed", "40")]  # a chain each
    report = tmp_path / "r.json"
    proc = _replay_until_two_verdicts(cluster, report, *paths)
    os.kill(_actor_pids(cluster)[0], signal.SIGKILL)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    assert "note: 1 Ray worker(s) died during the run" in out, out
    doc = json.loads(report.read_text())
    _each_once(doc, 16)
    for path in paths:
        histories = [e["index"] for e in doc["episodes"] if e["file"] == str(path)
                     and any("replayed for that" in note for note in e["notes"])]
        assert len(histories) <= 1, (path, histories)


def test_a_killed_driver_is_resumed_on_the_cluster_without_replaying_what_it_finished(cluster, record, tmp_path):
    path = record("PickCube-v1", 16, 30, *_OWN_SCENES)
    report = tmp_path / "r.json"
    proc = _replay_until_two_verdicts(cluster, report, path)
    proc.kill()
    proc.wait()
    before = len(_episode_lines(tmp_path / "r.jsonl"))
    resumed = subprocess.run([sys.executable, "-m", "simreel", "replay", "--resume", str(report), "--ray",
                              cluster.address, "--workers", "2", "-q"], capture_output=True, text=True,
                             timeout=600, env=cluster.env)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resumed {report}: {before} episode(s) already had their verdict" in resumed.stdout
    _each_once(json.loads(report.read_text()), 16)
    assert len(_episode_lines(tmp_path / "r.jsonl")) == 16  # nothing finished was replayed again


def test_ray_alone_starts_a_cluster_here_for_the_run(record, capsys):
    from simreel.cli.main import main

    assert main(["replay", str(record("PickCube-v1", 2, 8)), "--ray", "--workers", "1", "-q"]) == 0
    out, err = capsys.readouterr()
    assert "2 of 2 episode(s) verified (2 exact, 0 within tolerance); all verified" in out
    assert err == ""  # Ray's own logging stays out of the user's terminal
