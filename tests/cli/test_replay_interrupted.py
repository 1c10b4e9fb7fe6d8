"""A `simreel replay --report` run that is interrupted keeps every verdict it reached: killed with -9 (its worker
processes end with it) or stopped with Ctrl-C, `--resume` then replays only the episodes without a verdict, and
the report holds each episode exactly once. A run writing its replays (-o) or conversions publishes nothing after
Ctrl-C (an old output it was to replace stays byte for byte) and leaves no scratch recordings; those a kill -9 left are
cleared by the next run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

from simreel.formats import open_reader
from simreel.replay.run.output import scratch_folder

EPISODES = 12
"""The long run's episodes: at ~0.5 s each on two workers, a run interrupted after its third verdict has most to go."""


@pytest.fixture(scope="module")
def long_run(record) -> Path:
    """Enough episodes that a run is still going when it is interrupted after its first verdicts; every reset
    rebuilds the scene, so each episode is a scene chain of its own and `--workers 2` shares them between two
    processes (one chain is replayed in one: `simreel.replay.run.worklist.chain_groups`)."""
    return record("PickCube-v1", EPISODES, 20, "--env-kwargs", '{"reconfiguration_freq": 1}')


def _replay(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "simreel", "replay", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _episode_lines(log: Path) -> list[dict]:
    if not log.exists():
        return []
    return [json.loads(line) for line in log.read_text().splitlines(keepends=True)
            if line.endswith("\n") and '"type":"episode"' in line]


def _wait_for_verdicts(proc: subprocess.Popen, log: Path, count: int) -> None:
    deadline = time.monotonic() + 300
    while len(_episode_lines(log)) < count:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no verdicts after 300 s"
        time.sleep(0.1)


def _children(pid: int) -> list[int]:
    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            kids.append(int(stat.parent.name))
    return kids


def _alive(pids: list[int]) -> list[int]:
    return [p for p in pids if Path(f"/proc/{p}").exists() and "Z" not in Path(f"/proc/{p}/stat").read_text().split()[2]]


def _resume_and_check(report: Path, total: int, before: int) -> dict:
    done = subprocess.run([sys.executable, "-m", "simreel", "replay", "--resume", str(report), "-q"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert f"resumed {report}: {before} episode(s) already had their verdict" in done.stdout
    lines = _episode_lines(report.with_name(report.name + "l"))
    assert len(lines) == total and max(Counter(e["index"] for e in lines).values()) == 1  # each replayed once
    doc = json.loads(report.read_text())
    assert doc["complete"] is True and doc["ok"] is True and len(doc["episodes"]) == total
    return doc


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds worker processes through /proc")
def test_kill_9_of_the_driver_keeps_its_verdicts_ends_its_workers_and_resume_finishes(long_run, tmp_path):
    report = tmp_path / "r.json"
    proc = _replay(str(long_run), "--report", str(report), "--workers", "2", "-q")
    _wait_for_verdicts(proc, tmp_path / "r.jsonl", 3)
    workers = _children(proc.pid)
    assert workers  # the pool's process (and multiprocessing's resource tracker)
    proc.kill()
    proc.wait()
    before = len(_episode_lines(tmp_path / "r.jsonl"))
    assert 3 <= before < EPISODES, "the run ended before it could be killed: make the recording longer"
    deadline = time.monotonic() + 15
    while _alive(workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _alive(workers), "worker processes outlived their killed driver"
    assert not report.exists()  # kill -9 leaves the lines only; the document is written by the next run
    _resume_and_check(report, EPISODES, before)


def test_ctrl_c_writes_the_report_so_far_and_says_how_to_finish(long_run, tmp_path):
    report = tmp_path / "r.json"
    proc = _replay(str(long_run), "--report", str(report), "--workers", "2", "-q")
    _wait_for_verdicts(proc, tmp_path / "r.jsonl", 2)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    doc = json.loads(report.read_text())
    before = len(doc["episodes"])
    assert doc["complete"] is False and doc["totals"]["planned"] == EPISODES and 2 <= before < EPISODES
    # one line (it was two: how to finish, then "interrupted")
    assert err == (f"simreel replay: interrupted; {before} of {EPISODES} episodes have their verdict in {report}; finish with: "
                   f"simreel replay --resume {report}\n")
    _resume_and_check(report, EPISODES, before)
    assert os.path.getsize(report) > 0


def _wait_for_scratch(proc: subprocess.Popen, folder: Path) -> None:
    """Until a worker has written a replayed episode to the run's scratch folder."""
    deadline = time.monotonic() + 300
    while not list(folder.glob("episode_*.h5")):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, f"nothing in {folder} after 300 s"
        time.sleep(0.05)


def _wait_for_output(proc: subprocess.Popen, out: Path) -> None:
    """Until the HDF5 output `out` is being written (its writer's `.partial` folder is there)."""
    deadline = time.monotonic() + 300
    while not out.with_name(out.name + ".partial").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, f"{out} not begun after 300 s"
        time.sleep(0.05)


def _ctrl_c_once_scratch_is_written(proc: subprocess.Popen, out: Path) -> str:
    """Ctrl-C `proc` once its scratch folder holds an episode and its output is being written: it stops (130) and
    nothing of the folder stays. Returns what it said on stderr."""
    _wait_for_scratch(proc, scratch_folder(out))
    _wait_for_output(proc, scratch_folder(out) / "output.h5")  # -o is written there until the run is done
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert not scratch_folder(out).exists()
    return err


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_ctrl_c_of_a_run_writing_replays_keeps_the_output_it_was_to_replace(long_run, record, tmp_path):
    out = tmp_path / "out.h5"
    old = record("PickCube-v1", 1, 10)
    for suffix in (".h5", ".json"):
        out.with_suffix(suffix).write_bytes(old.with_suffix(suffix).read_bytes())
    before = _files(tmp_path)
    report = tmp_path / "r.json"
    err = _ctrl_c_once_scratch_is_written(_replay(str(long_run), "-o", str(out), "--report", str(report),
                                                  "--workers", "2", "--overwrite", "-q"), out)
    assert report.exists() and report.with_name("r.jsonl").exists()
    report.unlink()
    report.with_name("r.jsonl").unlink()
    assert _files(tmp_path) == before  # not a part of the run's replays in place of the old file
    # such a run cannot be resumed (`--resume` refuses it): the way on it names is to run it again
    assert err == (f"simreel replay: interrupted; {out} was not written; run it again (a run that writes replayed "
                   "episodes cannot be resumed)\n")


def test_ctrl_c_of_a_conversion_with_workers_publishes_nothing(long_run, tmp_path):
    """`convert --workers 2` writes episodes converted ahead of their turn to the same scratch folder as replay -o:
    Ctrl-C removes it, and drops the output, whose episodes were never checked against their source."""
    out = tmp_path / "out.h5"
    proc = subprocess.Popen([sys.executable, "-m", "simreel", "convert", str(long_run), str(out), "--obs-mode", "state",
                             "--workers", "2", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_scratch(proc, scratch_folder(out))
    _wait_for_output(proc, scratch_folder(out) / "output.h5")  # the output is written there until it is checked
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert list(tmp_path.iterdir()) == []


def test_a_scratch_folder_left_by_kill_9_is_cleared_by_the_next_run(long_run, tmp_path):
    out = tmp_path / "out.h5"
    proc = _replay(str(long_run), "-o", str(out), "--workers", "2", "-q")
    _wait_for_scratch(proc, scratch_folder(out))
    proc.kill()
    proc.wait()
    time.sleep(1.0)  # its pool's process notices within 0.5 s and ends
    assert scratch_folder(out).is_dir()  # nothing could remove it
    done = subprocess.run([sys.executable, "-m", "simreel", "replay", str(long_run), "-o", str(out), "--workers", "2",
                           "--overwrite", "-q"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert not scratch_folder(out).exists()
    with open_reader(out) as reader:
        assert [m.index for m in reader.episodes] == list(range(EPISODES))


def test_kill_9_of_a_run_writing_replays_leaves_no_part_of_it_at_the_output_name(long_run, tmp_path):
    """`-o` is written in the run's scratch folder and moved to its name once every episode is in it: a run killed
    with -9 after some episodes were written leaves no file at OUT (it once left them there, the recording's
    provenance saying it was a replay of the input, with no word that the others were missing), and the next run
    writing OUT clears what the killed one left."""
    out = tmp_path / "out.h5"
    proc = _replay(str(long_run), "-o", str(out), "--report", str(tmp_path / "r.json"), "-q")
    _wait_for_verdicts(proc, tmp_path / "r.jsonl", 2)
    proc.kill()
    proc.wait()
    assert len(_episode_lines(tmp_path / "r.jsonl")) < EPISODES, "the run ended before it could be killed"
    assert not out.exists() and not out.with_suffix(".json").exists()
    assert (scratch_folder(out) / "output.h5").is_file()  # the killed run's episodes, never under the output's name
    with open_reader(long_run) as r:
        first = r.episodes[0].index
    done = subprocess.run([sys.executable, "-m", "simreel", "replay", str(long_run), "-o", str(out), "--episodes",
                           str(first), "-q"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert not scratch_folder(out).exists()
    with open_reader(out) as r:
        assert [m.index for m in r.episodes] == [first]
