"""HDF5 format: round trips, kill -9 safety, and refusing files it cannot read."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from support.children import child_pids, wait_ended

from simreel import FORMAT_VERSION
from simreel.errors import RecordingFileError, UsageError
from simreel.formats import open_reader, open_writer
from simreel.formats.hdf5 import partial_dir, sidecar_path
from simreel.formats.hdf5.reader import datasets_below
from simreel.model.blocks import StepBlock
from simreel.model.episode import Episode
from simreel.model.fields import episode_fields
from simreel.model.meta import ContactChannel, EpisodeMeta, RecordingMeta
from simreel.model.state_tree import LeafSpec

SUPPORT = Path(__file__).parents[1] / "support"


def _meta() -> RecordingMeta:
    return RecordingMeta(
        env_id="PickCube-v1",
        control_mode="pd_joint_delta_pos",
        control_freq=20.0,
        sim_freq=100.0,
        action_space={"shape": [2], "dtype": "float32", "low": [-1, -1], "high": [1, 1]},
        state_layout={"actors/cube": LeafSpec((13,), "float32"), "goal": LeafSpec((1,), "float64")},
        info_layout={"is_grasped": LeafSpec((), "bool"), "elapsed_steps": LeafSpec((), "int32")},
        contact_channels=[ContactChannel("net", ("cube",)), ContactChannel("pair", ("panda/finger", "cube"))],
    )


def _episode(index: int, T: int, rng: np.random.Generator) -> Episode:
    return Episode(
        meta=EpisodeMeta(index=index, seed=100 + index, reset_options={"reconfigure": True}, length=T, success=True),
        actions=rng.standard_normal((T, 2)).astype(np.float32),
        rewards=rng.standard_normal(T).astype(np.float32),
        terminated=rng.random(T) > 0.5,
        truncated=np.zeros(T, bool),
        success=rng.random(T) > 0.5,
        fail=np.zeros(T, bool),
        env_states={
            "actors/cube": rng.standard_normal((T + 1, 13)).astype(np.float32),
            "goal": rng.standard_normal((T + 1, 1)),
        },
        info={"is_grasped": rng.random(T) > 0.5, "elapsed_steps": np.arange(1, T + 1, dtype=np.int32)},
        contact_forces=rng.standard_normal((T, 2, 3)).astype(np.float32),
    )


def test_round_trip_is_bit_exact_and_keeps_dtypes(tmp_path):
    rng = np.random.default_rng(0)
    episodes = [_episode(i, T, rng) for i, T in enumerate((7, 300, 0))]
    with open_writer(tmp_path / "r.h5", _meta()) as w:
        for ep in episodes:
            w.write_episode(ep)
    with open_reader(tmp_path / "r.h5") as r:
        assert r.meta == _meta().__class__.from_json(_meta().to_json())
        assert [m.index for m in r.episodes] == [0, 1, 2]
        for want in episodes:
            got = r.read_episode(want.meta.index)
            assert got.meta == want.meta
            for name in ("actions", "rewards", "terminated", "truncated", "success", "fail", "contact_forces"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
                assert getattr(got, name).dtype == getattr(want, name).dtype, name
            for group in ("env_states", "info"):
                assert getattr(got, group).keys() == getattr(want, group).keys()
                for k, a in getattr(want, group).items():
                    np.testing.assert_array_equal(getattr(got, group)[k], a)
                    assert getattr(got, group)[k].dtype == a.dtype
    assert not partial_dir(tmp_path / "r.h5").exists()


def test_the_walk_of_an_episode_group_finds_what_h5py_visititems_finds(tmp_path):
    """`datasets_below` (the fast walk every opened episode pays) against h5py's own ``visititems``, on a written
    episode with odd members added: a nested group, a soft link (not followed by either), a named datatype (no
    dataset) and a name that is no UTF-8 (bytes in both)."""
    with open_writer(tmp_path / "r.h5", _meta()) as w:
        w.write_episode(_episode(0, 4, np.random.default_rng(0)))
    with h5py.File(tmp_path / "r.h5", "r+") as f:
        group = f["traj_0"]
        group.create_dataset("extra/deeper/x", data=np.arange(3))
        group["alias"] = h5py.SoftLink("/traj_0/actions")
        group["kind"] = np.dtype("int16")
        h5py.h5d.create(group.id, b"caf\xe9", h5py.h5t.NATIVE_INT32, h5py.h5s.create_simple((2,)))
        seen = {}
        group.visititems(lambda name, obj: seen.__setitem__(name, obj.name) if isinstance(obj, h5py.Dataset) else None)
        walked = datasets_below(group)
        assert {name: ds.name for name, ds in walked.items()} == seen
        assert b"caf\xe9" in walked and "extra/deeper/x" in walked and "alias" not in walked
        np.testing.assert_array_equal(walked["extra/deeper/x"][:], np.arange(3))


def test_sidecar_is_maniskill_shaped(tmp_path):
    rng = np.random.default_rng(1)
    with open_writer(tmp_path / "r.h5", _meta()) as w:
        w.write_episode(_episode(0, 5, rng))
    side = json.loads(sidecar_path(tmp_path / "r.h5").read_text())
    assert side["env_info"]["env_id"] == "PickCube-v1"
    assert side["env_info"]["env_kwargs"]["control_mode"] == "pd_joint_delta_pos"
    ep = side["episodes"][0]
    assert (ep["episode_id"], ep["episode_seed"], ep["elapsed_steps"]) == (0, 100, 5)
    assert ep["reset_kwargs"] == {"seed": 100, "options": {"reconfigure": True}}


def test_existing_file_is_not_overwritten_unless_asked(tmp_path):
    path = tmp_path / "r.h5"
    with open_writer(path, _meta()) as w:
        w.write_episode(_episode(0, 3, np.random.default_rng(2)))
    before = path.read_bytes()
    with pytest.raises(UsageError, match="already exists; pass --overwrite"):
        open_writer(path, _meta())
    assert path.read_bytes() == before
    with pytest.raises(UsageError, match="does not exist"):
        open_writer(tmp_path / "missing" / "r.h5", _meta())


@pytest.mark.parametrize(
    ("make_side", "existing"),
    [
        (lambda p: sidecar_path(p).write_text('{"mine": 1}'), "r.json"),
        (lambda p: partial_dir(p).mkdir(), "r.h5.partial"),
    ],
    ids=["sidecar", "partial-folder"],
)
def test_existing_side_files_are_not_replaced_unless_asked(tmp_path, make_side, existing):
    """Regression: creating r.h5 deleted a user's r.json (and r.h5.partial/) although r.h5 did not exist."""
    path = tmp_path / "r.h5"
    make_side(path)
    with pytest.raises(UsageError) as err:
        open_writer(path, _meta())
    assert str(err.value) == (
        f"{tmp_path / existing} already exists and writing r.h5 would replace it; pass --overwrite to replace it "
        "(overwrite=True from Python)"
    )
    assert not path.exists() and (tmp_path / existing).exists()
    if existing.endswith(".json"):
        assert sidecar_path(path).read_text() == '{"mine": 1}'
    with open_writer(path, _meta(), overwrite=True) as w:
        w.write_episode(_episode(0, 3, np.random.default_rng(4)))
    assert json.loads(sidecar_path(path).read_text())["env_info"]["env_id"] == "PickCube-v1"
    assert not partial_dir(path).exists()
    with open_reader(path) as r:
        assert len(r) == 1


def test_a_failing_writer_constructor_removes_what_it_created(tmp_path, monkeypatch):
    import simreel.formats.hdf5.writer as hdf5_writer

    def boom(path, meta):
        raise RuntimeError("boom")

    monkeypatch.setattr(hdf5_writer, "SidecarFile", boom)
    with pytest.raises(RuntimeError, match="boom"):
        open_writer(tmp_path / "r.h5", _meta())
    assert sorted(tmp_path.iterdir()) == []


def test_remove_recording_removes_the_file_and_its_side_files(tmp_path):
    from simreel.formats import remove_recording

    path = tmp_path / "r.h5"
    w = open_writer(path, _meta())
    reset = StepBlock.of({"env_states/actors/cube": np.zeros((1, 13), np.float32), "env_states/goal": np.zeros((1, 1))})
    w.begin_episode(EpisodeMeta(index=0, seed=0), reset)
    (partial_dir(path) / "traj_0.h5").write_bytes(b"scratch")
    (tmp_path / "other.json").write_text("{}")
    remove_recording(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.json"]
    remove_recording(path)  # nothing left to remove: no error


def test_a_file_open_through_h5py_with_locking_is_reported_as_such(tmp_path):
    """Regression: an h5py.File of the recording open in the same process (h5py's default locking) was
    reported as a "truncated or corrupt HDF5 file"."""
    path = tmp_path / "r.h5"
    with open_writer(path, _meta()) as w:
        w.write_episode(_episode(0, 3, np.random.default_rng(5)))
    with h5py.File(path, "r"), pytest.raises(RecordingFileError) as err:
        open_reader(path)
    assert str(err.value).startswith(f"{path}: already open in this process through h5py with file locking on")
    assert "close that h5py.File, or open it with locking=False" in str(err.value)
    assert "corrupt" not in str(err.value)
    with h5py.File(path, "r", locking=False), open_reader(path) as r:  # the fix the message names works
        assert len(r) == 1


@pytest.mark.parametrize(
    "make_bad,problem",
    [
        (lambda p: None, "no such file"),
        (lambda p: p.write_bytes(b""), "empty file"),
        (lambda p: p.write_text("hello"), "neither an HDF5 nor an MCAP file"),
        (lambda p: h5py.File(p, "w").close(),
         "an HDF5 file that is neither a simreel recording (no simreel metadata) nor a ManiSkill trajectory file "
         "(no traj_N groups)"),
    ],
    ids=["missing", "empty", "foreign-bytes", "foreign-hdf5"],
)
def test_unreadable_files_raise_one_clear_error(tmp_path, make_bad, problem):
    path = tmp_path / "bad.h5"
    make_bad(path)
    with pytest.raises(RecordingFileError) as err:
        open_reader(path)
    assert str(err.value) == f"{path}: {problem}"


def test_truncated_and_newer_files_are_refused(tmp_path):
    path = tmp_path / "r.h5"
    with open_writer(path, _meta()) as w:
        w.write_episode(_episode(0, 50, np.random.default_rng(3)))
    data = path.read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingFileError, match="truncated or corrupt HDF5 file"):
        open_reader(cut)
    with h5py.File(path, "a") as f:
        f.attrs["simreel_format_version"] = FORMAT_VERSION + 1
    with pytest.raises(RecordingFileError, match="newer than this simreel reads"):
        open_reader(path)


def test_kill_9_keeps_every_committed_episode(tmp_path):
    """A real recording process killed mid-episode: every episode it committed is readable."""
    path = tmp_path / "killed.h5"
    child = subprocess.Popen([sys.executable, str(SUPPORT / "record_until_killed.py"), str(path)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    side = sidecar_path(path)
    deadline = time.monotonic() + 120
    committed = 0
    try:
        while committed < 3:
            assert child.poll() is None, "recording child died on its own"
            assert time.monotonic() < deadline, "child committed fewer than 3 episodes in 120 s"
            time.sleep(0.05)
            if side.exists():
                committed = len(json.loads(side.read_text())["episodes"])
        time.sleep(0.03)  # most likely in the middle of an episode now
    finally:
        writers = child_pids(child.pid)
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    assert len(writers) == 1
    wait_ended(writers)  # the writer process ends with its recorder
    with open_reader(path) as r:
        assert len(r) >= committed
        assert [m.index for m in r.episodes] == list(range(len(r)))
        for m in r.episodes:
            ep = r.read_episode(m.index)
            ep.check_shapes()
            assert ep.length == 50 and ep.meta.seed == m.index
            assert np.isfinite(ep.env_states["actors/cube"]).all()
        assert len(r.unfinished) <= 1
    out = subprocess.run([sys.executable, "-m", "simreel", "inspect", str(path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert f"episodes: {len(r)}," in out.stdout


def test_the_journal_names_only_the_episodes_still_running(tmp_path):
    """What a crash would leave (the file and its side folder copied mid-recording): the episodes the journal says
    began, less those discarded and those committed, are named as unfinished; a line a crash cut short is skipped.
    A closed recording leaves no side folder."""
    rng = np.random.default_rng(3)
    path, crashed = tmp_path / "r.h5", tmp_path / "crashed.h5"
    with open_writer(path, _meta()) as w:
        w.write_episode(_episode(0, 5, rng))
        discarded = _episode(1, 5, rng)
        w.begin_episode(discarded.meta, discarded.reset_block()).discard()
        running = _episode(2, 5, rng)
        sink = w.begin_episode(running.meta, running.reset_block())
        sink.append(running.steps_block())
        crashed.write_bytes(path.read_bytes())
        partial_dir(crashed).mkdir()
        journal = (partial_dir(path) / "running.jsonl").read_text()
        (partial_dir(crashed) / "running.jsonl").write_text(journal + '{"began": 3, "env_id')
        sink.discard()
    with open_reader(crashed) as r:
        assert [m.index for m in r.episodes] == [0]
        assert r.unfinished == ["episode 2 (env 0, seed 102; its steps were in memory)"]
    assert not partial_dir(path).exists()


def _end_of_data(path: Path) -> int:
    """The end-of-address field of the file's version-0 superblock: where HDF5's allocated space ends."""
    head = path.read_bytes()[:48]
    assert head[8] == 0, "simreel writes a version-0 superblock"
    return int.from_bytes(head[40:48], "little")


@pytest.mark.parametrize("overwrite", [False, True])
def test_each_commit_gives_back_the_disk_space_it_reserved_but_did_not_use(tmp_path, overwrite):
    """Regression: the space a commit reserves (an episode's raw size + 64 KiB) stayed at the end of the file as
    zeros, HDF5 never cutting it: half of a 226 KB conversion output. After every commit the file ends where
    HDF5's data ends, and h5py reads it."""
    rng = np.random.default_rng(1)
    path = tmp_path / "r.h5"
    if overwrite:
        path.write_bytes(b"an older recording")
    with open_writer(path, _meta(), overwrite=overwrite) as w:
        for i, T in enumerate((200, 50, 300, 0)):  # the first commit left 106 KB of zeros
            w.write_episode(_episode(i, T, rng))
            written = w._target.write_path  # the staged file while it replaces another
            assert written.stat().st_size == _end_of_data(written), f"after episode {i}"
    assert path.stat().st_size == _end_of_data(path)
    with h5py.File(path, "r") as f:
        assert f["traj_2/actions"].shape == (300, 2)


def _wide_meta(leaves: int) -> RecordingMeta:
    """A recording whose episodes hold `leaves` state datasets (a scene of many actors and articulations)."""
    layout = {f"actors/a{k // 4}/leaf{k % 4}": LeafSpec((13,), "float32") for k in range(leaves)}
    return dataclasses.replace(_meta(), state_layout=layout)


def _fill(meta: RecordingMeta, index: int, T: int, rng: np.random.Generator) -> Episode:
    arrays = {f.name: rng.standard_normal((f.row_count(T), *f.shape)).astype(f.dtype) for f in episode_fields(meta)}
    return Episode.from_fields(EpisodeMeta(index=index, seed=index, length=T), arrays)


@pytest.mark.parametrize("leaves", [2, 200])
def test_a_commit_changes_no_earlier_byte_of_the_file_before_its_flush(tmp_path, leaves):
    """The writer's metadata cache is bounded (so a commit does not slow down as the file grows) yet holds a whole
    commit's metadata: until a commit's flush, every byte the file held after the previous commit is unchanged
    (a commit only appends), also with 200 datasets per episode. A 16 KB cache rewrote root-group bytes mid-commit
    with PickCube's 16 datasets, as a 64 KB cache did with 200."""
    rng = np.random.default_rng(2)
    meta = _wide_meta(leaves)
    path = tmp_path / "r.h5"
    changed = []
    with open_writer(path, meta) as w:
        flush = w._file.flush

        def checked_flush() -> None:
            now = path.read_bytes()[: len(before)]
            changed.extend(i for i in np.flatnonzero(np.frombuffer(now, np.uint8) != np.frombuffer(before, np.uint8))
                           if before[i] != 0)  # zeros: space HDF5 had allocated, now written
            flush()

        w._file.flush = checked_flush
        for i in range(12):
            before = path.read_bytes()
            w.write_episode(_fill(meta, i, 20, rng))
        max_size = w._file.id.get_mdc_size()[0]
    assert not changed, f"bytes written before a commit's flush: {changed[:10]}"
    assert max_size < 1 << 20, "the writer's metadata cache grows as HDF5's default does"
    with open_reader(path) as r:
        assert len(r) == 12 and len(r.read_episode(11).env_states) == leaves


def test_a_short_episode_with_a_large_field_is_written_whole(tmp_path):
    """Regression: a field over the contiguous limit with fewer rows than a chunk (6 camera frames) failed
    ("Chunk shape must not be greater than data shape")."""
    import dataclasses

    meta = dataclasses.replace(_meta(), obs_layout={"rgb": LeafSpec((128, 128, 3), "uint8")})
    ep = _episode(0, 5, np.random.default_rng(3))
    ep.obs = {"rgb": np.random.default_rng(4).integers(0, 255, (6, 128, 128, 3), dtype=np.uint8)}
    with open_writer(tmp_path / "big.h5", meta) as w:
        w.write_episode(ep)
    with open_reader(tmp_path / "big.h5") as r:
        np.testing.assert_array_equal(r.read_episode(0).obs["rgb"], ep.obs["rgb"])


def test_image_like_observations_are_stored_in_chunks_of_frames_and_tiles():
    from simreel.formats.hdf5.writer import image_storage

    gzip = {"compression": "gzip", "compression_opts": 6}
    assert image_storage("obs/sensor_data/base_camera/rgb", (128, 128, 3), 61) == {"chunks": (32, 32, 32, 3), **gzip}
    assert image_storage("obs/sensor_data/base_camera/depth", (48, 64, 1), 9) == {"chunks": (9, 32, 32, 1), **gzip}
    assert image_storage("obs/pointcloud/xyzw", (16384, 4), 100) == {"chunks": (32, 1024, 4), **gzip}
    assert image_storage("obs/sensor_param/base_camera/cam2world_gl", (4, 4), 61) is None  # small: not an image
    assert image_storage("obs/agent/qpos", (9,), 61) is None and image_storage("env_states/x", (128, 128, 3), 9) is None


def test_camera_images_round_trip_compressed(tmp_path):
    """An episode with rgb observations: written with gzip in frame x tile chunks, read back bit-exact."""
    meta = _meta()
    meta.obs_layout = {"sensor_data/cam/rgb": LeafSpec((40, 36, 3), "uint8")}
    episode = _episode(0, 12, np.random.default_rng(0))
    frames = np.zeros((13, 40, 36, 3), np.uint8)
    frames[:, 10:20, 5:30] = np.arange(13, dtype=np.uint8)[:, None, None, None] * 9  # a moving block on black
    episode.obs = {"sensor_data/cam/rgb": frames}
    with open_writer(tmp_path / "cam.h5", meta) as w:
        w.write_episode(episode)
    with h5py.File(tmp_path / "cam.h5", "r") as f:
        stored = f["traj_0/obs/sensor_data/cam/rgb"]
        assert (stored.chunks, stored.compression) == ((13, 32, 32, 3), "gzip")
        assert stored.id.get_storage_size() < frames.nbytes / 10
    with open_reader(tmp_path / "cam.h5") as r:
        np.testing.assert_array_equal(r.read_episode(0).obs["sensor_data/cam/rgb"], frames)
