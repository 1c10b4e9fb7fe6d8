"""What keeps commits whole (`simreel.io.durable`): signals wait for a commit to end, and a full or read-only
disk stops a recording with one line and exit 2, every committed episode readable, no temporary file left — on
a small file system mounted for the test, with real recording processes."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys

import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write
from support.small_disk import fill, small_disk

from simreel.errors import Terminated
from simreel.formats import open_reader
from simreel.io.durable import deferred_signals, release_space, reserve_space


def simreel(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simreel", *args], capture_output=True, text=True, timeout=600)


def test_a_signal_during_a_commit_is_handled_right_after_it():
    events = []
    previous = signal.signal(signal.SIGTERM, lambda s, f: (_ for _ in ()).throw(Terminated()))
    try:
        with pytest.raises(KeyboardInterrupt), deferred_signals():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGTERM)
            events.append("the block ran to its end")
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert events == ["the block ran to its end"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers are back


def _committed(stderr: str) -> int:
    found = re.search(r"the (\d+) episode\(s\) committed before stay readable", stderr)
    assert found, stderr
    return int(found.group(1))


def test_hdf5_recording_on_a_full_disk_stops_with_one_line_and_keeps_every_committed_episode(tmp_path):
    """Regression: the recorder segfaulted or exited 3, and one half-written group made simreel refuse every
    episode of the file."""
    with small_disk(tmp_path, 4096) as disk:
        fill(disk, leave_kib=200)  # room for the file's header and one episode (its first commit needs ~160 KiB free)
        out = disk / "rec.h5"
        done = simreel("record", "PickCube-v1", "-o", str(out), "-n", "1000", "--max-steps", "20", "--record-obs", "-q")
        assert done.returncode == 2, done.stderr
        assert done.stderr.count("\n") == 1 and done.stderr.startswith(f"simreel record: error: {out}: the disk is full")
        assert done.stderr.rstrip().endswith("; free some space or write to another disk")
        committed = _committed(done.stderr)
        assert committed >= 1
        with open_reader(out) as r:
            assert [m.index for m in r.episodes] == list(range(committed))
            assert r.damaged == [] and r.unfinished == [] and r.notes == []
            for m in r.episodes:
                assert r.read_episode(m.index).length == 20
        sidecar = json.loads((disk / "rec.json").read_text())
        assert [e["episode_id"] for e in sidecar["episodes"]] == list(range(committed))
        assert {p.name for p in disk.iterdir()} - {"lost+found"} == {"filler", "rec.h5", "rec.json"}  # no temp file


def test_reserved_space_keeps_the_file_size_and_is_given_back(tmp_path, record):
    """A commit reserves its disk space past the end of the file without growing it: HDF5 cuts a longer file back
    at every flush, which freed the reserved blocks again (~1.6 ms a commit on ext4). What is left is given back
    when the writer closes."""
    path = tmp_path / "f.bin"
    path.write_bytes(b"x" * 10_000)
    with open(path, "r+b") as fh:
        before = os.fstat(fh.fileno())
        reserve_space(fh.fileno(), 1 << 20)
        reserved = os.fstat(fh.fileno())
        assert reserved.st_size == before.st_size
        if reserved.st_blocks == before.st_blocks:
            pytest.skip("this file system reserves no blocks past the end of a file")
        assert (reserved.st_blocks - before.st_blocks) * 512 >= 1 << 20
        release_space(fh.fileno())
        assert os.fstat(fh.fileno()).st_blocks == before.st_blocks
    done = record("PickCube-v1", 2, 20).stat()  # a real recording, closed: no reserved block left past its end
    assert done.st_blocks * 512 < done.st_size + 4096


def test_mcap_recording_on_a_full_disk_and_recovering_it(tmp_path):
    """Regression: exit 3, and `recover` in place failed on the full disk."""
    with small_disk(tmp_path, 4096) as disk:
        fill(disk, leave_kib=256)
        out = disk / "rec.mcap"
        done = simreel("record", "PickCube-v1", "-o", str(out), "-n", "1000", "--max-steps", "20", "-q")
        assert done.returncode == 2, done.stderr
        assert done.stderr.count("\n") == 1 and done.stderr.startswith(f"simreel record: error: {out}: the disk is full")
        assert f"stay readable through `simreel recover {out}`" in done.stderr
        committed = _committed(done.stderr)
        cut = out.read_bytes()
        fill(disk, leave_kib=0)  # no room to rewrite it in place
        in_place = simreel("recover", str(out))
        assert in_place.returncode == 2
        assert in_place.stderr == (f"simreel recover: error: {out}: the disk is full; nothing was written and {out} is "
                                   "unchanged; free some space or write to another disk\n")
        assert out.read_bytes() == cut and not (disk / "rec.mcap.partial").exists()
        saved = tmp_path / "saved.mcap"
        assert simreel("recover", str(out), "-o", str(saved)).returncode == 0
    with open_reader(saved) as r:
        assert [m.index for m in r.episodes] == list(range(committed))
        for m in r.episodes:
            assert r.read_episode(m.index).length == 20


@pytest.mark.parametrize("command", ["record", "convert", "replay-report", "recover-o"])
def test_a_read_only_folder_is_one_line_and_exit_2(tmp_path, command):
    meta = synthetic_meta()
    src = write(tmp_path / "src.mcap", meta, [synthetic_episode(meta, 0, 3)])
    with small_disk(tmp_path, 1024) as disk:
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        argv = {
            "record": ["record", "PickCube-v1", "-o", str(disk / "x.h5"), "--max-steps", "2", "-q"],
            "convert": ["convert", str(src), str(disk / "x.h5"), "-q"],
            "replay-report": ["replay", str(src), "--report", str(disk / "r.json"), "-q"],
            "recover-o": ["recover", str(src), "-o", str(disk / "x.mcap")],
        }[command]
        done = simreel(*argv)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert f"folder {disk} is not writable" in done.stderr
