"""`replay -o` with worker processes (`ReplayRun` with ``output`` and ``workers=2``): episodes replayed in the pool's
process, or here out of their turn, go through scratch recordings and reach the output the same as with one worker
(arrays, dtypes and metadata, apart from the time, command line and id), for HDF5 and MCAP outputs; the run's scratch
folder is gone when it ends, also when an episode fails with an error or the env does not build; a folder left by
a killed run is cleared by the next, one held by a live run is refused."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from support.damage import corrupt_chunk
from support.small_disk import fill, small_disk

from simreel.errors import EnvBuildError, StorageError, UsageError
from simreel.formats import open_reader
from simreel.io.lock import WriterLock
from simreel.replay.run.output import scratch_folder
from simreel.replay.run.verify import verify_recording

_RUN_ONLY = {"created_utc", "command", "recording_id"}
"""Metadata of an output that says when and how it was made, not what it holds."""


def _assert_same_output(a, b) -> None:
    with open_reader(a) as one, open_reader(b) as two:
        left, right = one.meta.to_json(), two.meta.to_json()
        assert {k: v for k, v in left.items() if k not in _RUN_ONLY} == \
            {k: v for k, v in right.items() if k not in _RUN_ONLY}
        assert [m.to_json() for m in one.episodes] == [m.to_json() for m in two.episodes]
        for m in one.episodes:
            x, y = one.read_episode(m.index).fields(), two.read_episode(m.index).fields()
            assert list(x) == list(y)
            for name in x:
                assert x[name].dtype == y[name].dtype, name
                np.testing.assert_array_equal(x[name], y[name], err_msg=name)


_OWN_SCENES = ("--env-kwargs", '{"reconfiguration_freq": 1}')
"""Every reset rebuilds the scene: each episode is a scene chain of its own, which any process may replay (the
episodes of one chain are replayed in one process: `simreel.replay.run.worklist.chain_groups`)."""


def _workers_of(report) -> set[str]:
    lines = [json.loads(line) for line in report.with_name(report.name + "l").read_text().splitlines()]
    return {e["worker"] for e in lines if e["type"] == "episode"}


@pytest.mark.parametrize("fmt", ["h5", "mcap"])
def test_output_of_two_workers_equals_output_of_one(record, tmp_path, fmt):
    path = record("PickCube-v1", 4, 20, *_OWN_SCENES)
    one, two = tmp_path / f"one.{fmt}", tmp_path / f"two.{fmt}"
    verify_recording(path, output=str(one))
    report = verify_recording(path, output=str(two), workers=2, report=str(tmp_path / "r.json"))
    assert [e.verdict for e in report.episodes] == ["exact"] * 4
    assert len(_workers_of(tmp_path / "r.json")) == 2  # the pool's process replayed some of them
    _assert_same_output(one, two)
    with open_reader(two) as reader:
        assert [m.verification.verdict for m in reader.episodes] == ["exact"] * 4
    assert not scratch_folder(two).exists()
    if fmt == "h5":  # ManiSkill's sidecar too, apart from the command line it names
        sidecars = [json.loads(p.with_suffix(".json").read_text()) for p in (one, two)]
        for doc in sidecars:
            doc.pop("source_desc")
        assert sidecars[0] == sidecars[1]


def test_an_episode_that_fails_leaves_no_scratch_and_the_others_are_written(record, tmp_path):
    path = tmp_path / "damaged.h5"
    shutil.copy(record("PickCube-v1", 4, 20, *_OWN_SCENES), path)
    corrupt_chunk(path, "traj_1/actions", 2)
    out = tmp_path / "out.h5"
    report = verify_recording(path, output=str(out), workers=2, report=str(tmp_path / "r.json"))
    assert len(_workers_of(tmp_path / "r.json")) == 2
    assert [e.verdict for e in report.episodes] == ["exact", "error", "exact", "exact"]
    with open_reader(out) as reader:
        assert [m.index for m in reader.episodes] == [0, 2, 3]
    assert not scratch_folder(out).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["damaged.h5", "out.h5", "out.json", "r.json", "r.jsonl"]


@pytest.mark.parametrize("fmt", ["h5", "mcap"])
def test_an_output_the_disk_cannot_hold_is_dropped_and_the_old_one_kept(record, tmp_path, fmt):
    """The disk fills while -o is written: the run stops with one line saying nothing was written (not "the episodes
    committed before stay readable", which the dropped output's writer had said), and the file it was to replace
    is as it was."""
    path = record("PickCube-v1", 8, 30)
    with small_disk(tmp_path, 1024) as disk:
        out = disk / f"out.{fmt}"
        verify_recording(record("PickCube-v1", 1, 10), output=str(out))
        old = {p.name: p.read_bytes() for p in disk.iterdir() if p.is_file()}  # an ext2 image has lost+found
        fill(disk, leave_kib=48)
        with pytest.raises(StorageError, match=rf"the disk is full; nothing was written to .*out\.{fmt}; free some"):
            verify_recording(path, output=str(out), overwrite=True)
        assert {p.name: p.read_bytes() for p in disk.iterdir() if p.is_file() and "filler" not in p.name} == old


def test_a_disk_that_fills_in_the_middle_of_the_last_episode_stops_the_run_and_drops_the_output(record, tmp_path):
    """One long episode: MCAP writes a chunk of it while it is replayed (not at its commit), and the disk fills
    there. Dropping what was written of the episode raises the writer's failure again; that must not turn the
    output's failure into the episode's own error, after which the run would go on and publish a broken file."""
    path = record("PickCube-v1", 1, 600, "--record-obs")
    with small_disk(tmp_path, 64) as disk:
        out = disk / "out.mcap"
        with pytest.raises(StorageError, match=r"the disk is full; nothing was written to .*out\.mcap; free some"):
            verify_recording(path, output=str(out))
        assert [p for p in disk.iterdir() if p.name != "lost+found"] == []


def test_a_run_whose_env_does_not_build_leaves_no_scratch(record, tmp_path):
    out = tmp_path / "out.h5"
    with pytest.raises(EnvBuildError):
        verify_recording(record("PickCube-v1", 4, 20, *_OWN_SCENES), output=str(out), workers=2,
                         imports=("no_such_module_13",))
    assert list(tmp_path.iterdir()) == []


def test_a_scratch_folder_left_by_a_killed_run_is_cleared_and_a_live_one_refused(record, tmp_path):
    path = record("PickCube-v1", 2, 20)
    out = tmp_path / "out.h5"
    left = scratch_folder(out)
    left.mkdir()
    (left / "lock").touch()
    (left / "episode_1.h5").write_bytes(b"\x89HDF\r\n\x1a\n half written")
    verify_recording(path, output=str(out), workers=2)
    assert not left.exists()
    with open_reader(out) as reader:
        assert [m.index for m in reader.episodes] == [0, 1]

    busy = scratch_folder(tmp_path / "out2.h5")
    busy.mkdir()
    lock = WriterLock.acquire(busy / "lock", create=True)  # as a run writing the same output holds it
    try:
        with pytest.raises(UsageError, match=r"out2\.h5 is being written by another replay"):
            verify_recording(path, output=str(tmp_path / "out2.h5"), workers=2)
        assert (busy / "lock").exists()  # left to the run that holds it
    finally:
        lock.release()
    assert not (tmp_path / "out2.h5").exists()


def test_verify_recording_of_a_folder_of_several_recordings_is_refused_before_replaying(record, tmp_path):
    """It replayed every episode of every file, then failed on its own unpacking of the one file it expected (a raw
    ValueError, the work lost)."""
    folder = tmp_path / "ds"
    folder.mkdir()
    for name in ("a", "b"):
        shutil.copy(record("PickCube-v1", 1, 5), folder / f"{name}.h5")
    replayed = []
    with pytest.raises(UsageError, match=r"verify_recording verifies one recording, and .*ds names 2 \(.*a\.h5, "
                                         r".*b\.h5\): pass one file, or use ReplayRun for several"):
        verify_recording(folder, progress=replayed.append)
    assert replayed == []
