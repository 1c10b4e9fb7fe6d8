"""HDF5 under faults: readers of a file being recorded, damaged bytes (detected, never read as good, never a hang),
episodes that do not fit their own layout, and files of the first HDF5 format."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from support.children import SUPPORT, RecordingChild, simreel
from support.damage import stored_bytes, write_format1
from support.mcap_samples import (
    assert_same_episode,
    only_this_episode_fails,
    sample,
    synthetic_episode,
    synthetic_meta,
)

from simreel.errors import RecordingFileError
from simreel.formats import open_reader


def _sample(tmp_path: Path, name: str = "rec.h5", n: int = 3) -> tuple[Path, list]:
    return sample(tmp_path / name, n)


# ----------------------------------------------------------------------------------- reading while recording
def test_readers_see_the_committed_episodes_of_a_file_being_recorded(tmp_path):
    """Regression: `inspect`, `convert`, `replay` of a file being recorded exited 3 or called it corrupt in 20 of
    32 runs. Episodes of 2 steps commit every few milliseconds, so reads land in the middle of commits."""
    path = tmp_path / "live.h5"
    with RecordingChild(str(path), "--steps", "2") as child:
        child.wait_committed(3)
        seen = 0
        for k in range(40):
            with open_reader(path) as r:
                assert r.damaged == [] and r.live
                assert len(r.episodes) >= seen and [m.index for m in r.episodes] == list(range(len(r.episodes)))
                seen = len(r.episodes)
                for m in r.episodes[-3:] if k % 4 == 0 else []:
                    assert r.read_episode(m.index).length == 2
        for command in (["inspect", str(path)], ["convert", str(path), str(tmp_path / "copy.mcap"), "-q"]):
            done = simreel(*command)
            assert done.returncode == 0, done.stderr
        saved = simreel("recover", str(path), "-o", str(tmp_path / "saved.h5"))
        assert saved.returncode == 0, saved.stderr  # the running episode is not lost: the recording goes on
        assert "lost: nothing so far (the recording still runs: its running episodes are not in the copy)" in saved.stdout
        child.wait_committed(child.committed + 3)
    with open_reader(tmp_path / "copy.mcap") as r:
        assert len(r.episodes) >= 3


def test_a_kill_9_names_the_running_episode_and_the_sidecar_lists_every_committed_one(tmp_path):
    """Regression (issue 16): after `kill -9` of an HDF5 recording `inspect` did not name the episode that was
    running, and the JSON sidecar lagged the .h5 by several episodes."""
    import time

    path = tmp_path / "killed.h5"
    with RecordingChild(str(path), "--steps", "300") as child:
        child.wait_committed(3)
        time.sleep(0.1)  # in the middle of the next episode (300 steps take ~0.5 s or more)
        child.signal()
    committed = child.committed  # as the child said before it was killed (an episode more, on a fast machine)
    inspect = simreel("inspect", str(path))
    assert inspect.returncode == 0, inspect.stderr
    assert f"episodes: {committed}," in inspect.stdout
    assert ("warning: 1 episode(s) were still running when the recording process stopped and were not committed: "
            f"episode {committed} (env 0, seed {committed}; its steps were in memory)") in inspect.stdout
    sidecar = json.loads(path.with_suffix(".json").read_text())
    assert [e["episode_id"] for e in sidecar["episodes"]] == list(range(committed))
    with h5py.File(path, "r") as f:  # plain h5py, file locking on, as ManiSkill's tools open it
        assert sorted(f) == [f"traj_{i}" for i in range(committed)]
        assert f["traj_0/actions"].shape == (300, 8)


# ----------------------------------------------------------------------------------- damaged bytes
def test_a_damaged_chunk_is_reported_as_corrupt_and_the_other_episodes_read(tmp_path):
    """Regression: HDF5 data had no checksum; damaged bytes were read as good data (56 of 56 cases, exit 0)."""
    path, episodes = _sample(tmp_path)
    offset, size = stored_bytes(path, "traj_1/env_states/actors/cube")
    data = bytearray(path.read_bytes())
    data[offset + size // 2] ^= 0x01
    path.write_bytes(data)
    err = only_this_episode_fails(path, episodes, 1)
    assert str(err).startswith(f"{path}: traj_1/env_states/actors/cube is corrupt: its data fails its checksum")


def test_replay_calls_a_corrupt_episode_corrupt_never_verified(record, tmp_path):
    src = record("PickCube-v1", 2, 20)
    path = tmp_path / "damaged.h5"
    path.write_bytes(src.read_bytes())
    offset, size = stored_bytes(path, "traj_1/actions")
    data = bytearray(path.read_bytes())
    data[offset + size // 2] ^= 0x10
    path.write_bytes(data)
    done = simreel("replay", str(path), "-q")
    assert done.returncode == 2, done.stderr
    row = next(line.split(None, 3) for line in done.stdout.splitlines() if line.split()[:1] == ["1"])
    assert row == ["1", "20", "error", "traj_1/actions is corrupt: its data fails its checksum or cannot be "
                   "decompressed (Can't synchronously read data (filter returned failure during read))"]
    assert done.stdout.splitlines()[-1] == ("1 of 2 episode(s) verified (1 exact, 0 within tolerance); none diverged; "
                                            "1 could not be replayed")


def _sweep(path: Path, how: str, step: int, timeout: float) -> list[str]:
    """Run `support/damage.py` on `path` in a child process; fail naming the offset where a reader hung."""
    try:
        done = subprocess.run([sys.executable, str(SUPPORT / "damage.py"), str(path), how, str(step)],
                              capture_output=True, text=True, timeout=timeout, cwd=SUPPORT.parent)
    except subprocess.TimeoutExpired as e:
        lines = (e.stdout or b"").decode().splitlines()
        pytest.fail(f"a reader hung after {lines[-1] if lines else 'the start'} ({how})")
    lines = done.stdout.splitlines()
    assert lines[-1] == "done", done.stderr[-3000:]
    return lines[:-1]


@pytest.mark.slow  # minutes: thousands of damaged copies
@pytest.mark.parametrize("how", ["flip", "zero64"])
def test_no_damage_is_read_as_good_data_and_no_reader_hangs(tmp_path, how):
    """Damage a small recording at every 5th byte (one byte inverted, or 64 bytes zeroed): each time the reader
    refuses the file, names a damaged episode, raises on a corrupt one, or reads exactly what was written."""
    path, _ = _sample(tmp_path, n=2)
    outcomes = _sweep(path, how, 5, timeout=900)
    bad = [line for line in outcomes if line.split(" ", 1)[1] not in ("ok", "refused", "damaged", "corrupt")]
    assert not bad, bad[:10]
    assert sum(line.endswith(" corrupt") for line in outcomes) > 10  # data damage is found, not just headers


def _free_space_of_global_heap(data: bytes) -> int:
    """The offset of the free-space object of the file's global heap collection (walked as libhdf5 walks it)."""
    heap = data.index(b"GCOL\x01")
    pos = heap + 16
    while True:
        index, _, _, size = struct.unpack_from("<HHIQ", data, pos)
        if index == 0:
            return pos
        pos += 16 + (size + 7) // 8 * 8


def test_zeroed_bytes_in_a_first_format_file_do_not_hang_the_reader(tmp_path):
    """Regression: `inspect`/`convert` hung forever inside libhdf5 on a file with 64 zeroed bytes: in a global heap
    of a file of the first format (where simreel kept its attributes), an object of size 0 where libhdf5 expects
    the heap's free space makes it loop."""
    meta = synthetic_meta(poses=False)
    path = write_format1(tmp_path / "old.h5", meta, [synthetic_episode(meta, i, 4) for i in range(2)])
    with open_reader(path) as r:  # the undamaged file of the first format still reads
        assert [m.index for m in r.episodes] == [0, 1]
        assert_same_episode(r.read_episode(1), synthetic_episode(meta, 1, 4))
    data = bytearray(path.read_bytes())
    free = _free_space_of_global_heap(data)
    data[free : free + 64] = bytes(64)
    broken = tmp_path / "zeroed.h5"
    broken.write_bytes(data)
    for command in (["inspect", str(broken)], ["convert", str(broken), str(tmp_path / "out.mcap"), "-q"]):
        done = simreel(*command, timeout=120)  # a hang fails here, as a timeout
        assert done.returncode == 2
        assert done.stderr == (f"simreel {command[0]}: error: {broken}: corrupt HDF5 file (a global heap object at byte "
                               f"{free} is empty, which would make libhdf5 loop)\n")


# ----------------------------------------------------------------------------------- the file against its layout
def _edit(path: Path, edit) -> None:
    with h5py.File(path, "a") as f:
        edit(f)


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda f: f.create_dataset("traj_1/env_states/extra", data=np.zeros((7, 2), np.float32)),
         "traj_1 holds env_states/extra, which the recording's layout does not list (a damaged or altered file)"),
        (lambda f: (f.__delitem__("traj_1/info/is_grasped"),),
         "traj_1 lacks info/is_grasped, which the recording's layout lists"),
        (lambda f: (f.__delitem__("traj_1/contact_forces"),),
         "traj_1 lacks contact_forces, which the recording's layout lists"),
        (lambda f: (f.__delitem__("traj_1/rewards"), f.create_dataset("traj_1/rewards", data=np.zeros(6))),
         "traj_1/rewards is float64 (6,), the layout says float32 (6,)"),
        (lambda f: (f.__delitem__("traj_1/env_states/goal"),
                    f.create_dataset("traj_1/env_states/goal", data=np.zeros((6, 2)))),
         "traj_1/env_states/goal is float64 (6, 2), the layout says float64 (7, 2)"),
    ],
    ids=["extra-dataset", "missing-info", "missing-contacts", "wrong-dtype", "wrong-rows"],
)
def test_an_episode_that_does_not_fit_its_layout_is_refused_naming_what(tmp_path, edit, problem):
    """Regression: `convert` dropped arrays the metadata did not list and cast wrong dtypes silently."""
    path, episodes = _sample(tmp_path)
    _edit(path, edit)
    with open_reader(path) as r:
        assert_same_episode(r.read_episode(0), episodes[0])
        with pytest.raises(RecordingFileError) as err:
            r.read_episode(1)
    assert str(err.value) == f"{path}: {problem}"
    done = simreel("convert", str(path), str(tmp_path / "out.mcap"), "-q")
    assert done.returncode == 2 and problem in done.stderr and not (tmp_path / "out.mcap").exists()


def test_a_flipped_byte_in_an_episode_attribute_name_is_named_not_dropped(tmp_path):
    """Regression: one flipped byte in an episode's attribute name made it vanish silently from inspect and convert."""
    path, episodes = _sample(tmp_path)
    data = bytearray(path.read_bytes())
    second = data.index(b"simreel_episode", data.index(b"simreel_episode") + 1)
    data[second + 9] ^= 0x01  # simreel_episode -> simreel_dpisode
    path.write_bytes(data)
    with open_reader(path) as r:
        assert [m.index for m in r.episodes] == [0, 2]
        assert len(r.damaged) == 1 and r.damaged[0].startswith("traj_1: ")
    inspect = simreel("inspect", str(path))
    assert inspect.returncode == 1 and "warning: damaged, not readable: traj_1: " in inspect.stdout
    convert = simreel("convert", str(path), str(tmp_path / "out.mcap"), "-q")
    assert convert.returncode == 2
    assert "1 damaged episode(s) (traj_1: " in convert.stderr and f"simreel recover {path} -o" in convert.stderr
    recovered = simreel("recover", str(path), "-o", str(tmp_path / "saved.h5"))
    assert recovered.returncode == 0 and "lost (damaged): traj_1: " in recovered.stdout
    with open_reader(tmp_path / "saved.h5") as r:
        assert [m.index for m in r.episodes] == [0, 2] and r.damaged == []
        assert_same_episode(r.read_episode(2), episodes[2])
