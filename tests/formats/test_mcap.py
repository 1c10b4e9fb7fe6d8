"""MCAP format: bit-exact round trips with HDF5, channels Rerun and Foxglove read, time, kill -9 recovery, bad input."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.children import child_pids, wait_ended
from support.foxglove import descriptor_set
from support.mcap_samples import assert_same_episode, long_sample, synthetic_episode, synthetic_meta, write

from simreel.datasets.copy import convert, recover
from simreel.errors import EpisodeLayoutError, RecordingFileError, SimreelError, UsageError
from simreel.formats import open_reader
from simreel.formats.mcap import TOPICS, McapReader, McapWriter
from simreel.model.episode import Episode
from simreel.model.fields import episode_fields

SUPPORT = Path(__file__).parents[1] / "support"


# ----------------------------------------------------------------------------------- helpers
def messages(path: Path, topic: str) -> list:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return list(make_reader(fh).iter_messages(topics=[topic], log_time_order=False))


def time_origin(path: Path) -> int:
    """The log time of the recording's first row, as its `simreel` record states it."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        record = next(m for m in make_reader(fh).iter_metadata() if m.name == "simreel")
    return int(record.metadata["time_origin_ns"])


def simreel_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simreel", *args], capture_output=True, text=True, timeout=120)


# ----------------------------------------------------------------------------------- real recordings
def _record(path: Path, episodes: int = 2, steps: int = 15) -> Path:
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    rec = RecordWrapper(make_env("PickCube-v1"), path, poses=True, block_steps=8)
    rng = np.random.default_rng(0)
    try:
        for k in range(episodes):
            rec.reset(seed=k)
            for _ in range(steps):
                rec.step(rng.uniform(-1, 1, 8).astype(np.float32))
    finally:
        rec.close()
    return path


@pytest.fixture(scope="module")
def pickcube_mcap(tmp_path_factory) -> Path:
    """2 PickCube episodes × 15 steps recorded straight into MCAP (with body poses, blocks of 8 steps)."""
    return _record(tmp_path_factory.mktemp("mcap") / "pickcube.mcap")


@pytest.fixture(scope="module")
def pickcube_h5(tmp_path_factory) -> Path:
    """The same, recorded into HDF5."""
    return _record(tmp_path_factory.mktemp("h5") / "pickcube.h5")


# ----------------------------------------------------------------------------------- round trips
def test_synthetic_round_trip_is_bit_exact(tmp_path):
    meta = synthetic_meta()
    episodes = [synthetic_episode(meta, i, T) for i, T in enumerate((5, 600, 0, 1))]
    write(tmp_path / "s.mcap", meta, episodes)
    with open_reader(tmp_path / "s.mcap") as r:
        assert isinstance(r, McapReader)
        assert r.meta.to_json() == meta.to_json()
        assert [m.index for m in r.episodes] == [0, 1, 2, 3] and r.unfinished == []
        for want in episodes:
            assert_same_episode(r.read_episode(want.meta.index), want)


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_other_compressions_round_trip(tmp_path, compression):
    meta = synthetic_meta()
    ep = synthetic_episode(meta, 0, 40)
    write(tmp_path / "s.mcap", meta, [ep], compression=compression, chunk_size=4096)
    with open_reader(tmp_path / "s.mcap") as r:
        assert_same_episode(r.read_episode(0), ep)


def test_h5_to_mcap_to_h5_is_lossless(pickcube_h5, tmp_path):
    convert(pickcube_h5, tmp_path / "a.mcap")
    convert(tmp_path / "a.mcap", tmp_path / "b.h5")
    with open_reader(pickcube_h5) as src, open_reader(tmp_path / "a.mcap") as mid, open_reader(tmp_path / "b.h5") as dst:
        assert src.meta.to_json() == mid.meta.to_json() == dst.meta.to_json()
        assert src.meta.pose_bodies and len(src.episodes) == 2
        for m in src.episodes:
            want = src.read_episode(m.index)
            assert_same_episode(mid.read_episode(m.index), want)
            assert_same_episode(dst.read_episode(m.index), want)


def test_recorded_mcap_to_h5_to_mcap_is_lossless(pickcube_mcap, tmp_path):
    convert(pickcube_mcap, tmp_path / "a.h5")
    convert(tmp_path / "a.h5", tmp_path / "b.mcap")
    with open_reader(pickcube_mcap) as src, open_reader(tmp_path / "b.mcap") as dst:
        assert [m.length for m in src.episodes] == [15, 15]
        for m in src.episodes:
            want = src.read_episode(m.index)
            assert want.body_poses.shape == (16, len(src.meta.pose_bodies), 7)
            assert_same_episode(dst.read_episode(m.index), want)


# ----------------------------------------------------------------------------------- viewable channels
def test_rerun_mcap_reader_decodes_transforms_of_every_body(pickcube_mcap):
    import rerun.chunk as rc

    with open_reader(pickcube_mcap) as r:
        bodies = r.meta.pose_bodies
        episodes = [r.read_episode(m.index) for m in r.episodes]
    step_ns = 50_000_000  # PickCube: 20 Hz control
    origin = time_origin(pickcube_mcap)
    want = {}  # (log time, frame) → pose, episodes laid end to end on the time axis
    for k, ep in enumerate(episodes):
        for row in range(ep.length + 1):
            for b, name in enumerate(bodies):
                want[(origin + (k * (ep.length + 1) + row) * step_ns, name)] = ep.body_poses[row, b]
    got = {}
    reader = rc.McapReader(pickcube_mcap, include_topic_regex=["^/tf$"], timeline_type="duration_ns")
    for chunk in reader.stream().to_chunks():
        batch = chunk.to_record_batch()
        if "Transform3D:child_frame" not in batch.schema.names:
            continue
        times = batch.column("message_log_time").cast("int64").to_pylist()
        for t, parent, child, xyz, xyzw in zip(
            times,
            batch.column("Transform3D:parent_frame").to_pylist(),
            batch.column("Transform3D:child_frame").to_pylist(),
            batch.column("Transform3D:translation").to_pylist(),
            batch.column("Transform3D:quaternion").to_pylist(),
            strict=True,
        ):
            assert parent == ["world"]
            got[(t, child[0])] = (xyz[0], xyzw[0])
    assert {name for _, name in got} == set(bodies)
    assert got.keys() == want.keys()
    for key, pose in want.items():
        xyz, xyzw = got[key]
        np.testing.assert_array_equal(np.float32(xyz), pose[:3])  # Rerun stores float32: exact here
        np.testing.assert_array_equal(np.float32(xyzw), pose[[4, 5, 6, 3]])  # wxyz → xyzw


def test_time_axis_sequence_and_plots(pickcube_mcap):
    tf = messages(pickcube_mcap, TOPICS["tf"])
    origin = time_origin(pickcube_mcap)
    assert [m.log_time - origin for _, _, m in tf] == [i * 50_000_000 for i in range(32)]  # 2 episodes × 16 rows
    assert [m.sequence for _, _, m in tf] == list(range(16)) * 2  # sequence = row (step) index
    plots = [json.loads(m.data) for _, _, m in messages(pickcube_mcap, TOPICS["plots"])]
    assert [(p["episode"], p["step"]) for p in plots] == [(e, s) for e in (0, 1) for s in range(15)]
    with open_reader(pickcube_mcap) as r:
        ep = r.read_episode(1)
    # the same float32 numbers, written with the fewest digits that read back as them
    np.testing.assert_array_equal(np.float32([p["reward"] for p in plots[15:]]), ep.rewards)
    assert max(len(json.dumps(p["reward"])) for p in plots) <= 16
    assert [p["success"] for p in plots[15:]] == ep.success.tolist()
    log = messages(pickcube_mcap, TOPICS["log"])
    assert len(log) == 4  # begin + commit of each episode


def test_foxglove_schemas_are_foxgloves_own_and_messages_decode(pickcube_mcap):
    pytest.importorskip("google.protobuf")
    fgp = pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf import FrameTransforms_pb2, Log_pb2

    assert fgp is not None
    tf = messages(pickcube_mcap, TOPICS["tf"])
    schema = tf[0][0]
    assert (schema.name, schema.encoding) == ("foxglove.FrameTransforms", "protobuf")
    assert schema.data == descriptor_set(FrameTransforms_pb2.FrameTransforms.DESCRIPTOR)
    with open_reader(pickcube_mcap) as r:
        bodies, ep = r.meta.pose_bodies, r.read_episode(0)
    origin = time_origin(pickcube_mcap)
    for row in (0, 7, 15):
        msg = FrameTransforms_pb2.FrameTransforms.FromString(tf[row][2].data)
        assert [t.child_frame_id for t in msg.transforms] == bodies
        for b, t in enumerate(msg.transforms):
            assert t.timestamp.ToNanoseconds() == origin + row * 50_000_000
            p = ep.body_poses[row, b].astype(np.float64)
            assert [t.translation.x, t.translation.y, t.translation.z] == p[:3].tolist()
            assert [t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w] == p[[4, 5, 6, 3]].tolist()
    log = messages(pickcube_mcap, TOPICS["log"])
    assert log[0][0].data == descriptor_set(Log_pb2.Log.DESCRIPTOR)
    texts = [Log_pb2.Log.FromString(m.data).message for _, _, m in log]
    assert texts[0].startswith("episode 0 begins") and texts[1].startswith("episode 0 committed: 15 steps")


def test_without_body_poses_tf_shows_state_actors_and_articulation_roots(tmp_path):
    meta = synthetic_meta(poses=False)
    ep = synthetic_episode(meta, 0, 3)
    write(tmp_path / "s.mcap", meta, [ep])
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf import FrameTransforms_pb2

    tf = messages(tmp_path / "s.mcap", TOPICS["tf"])
    assert len(tf) == 4
    msg = FrameTransforms_pb2.FrameTransforms.FromString(tf[2][2].data)
    assert [t.child_frame_id for t in msg.transforms] == ["cube", "robot/base"]
    root = ep.env_states["articulations/robot"][2, :7].astype(np.float64)
    t = msg.transforms[1]
    assert [t.translation.x, t.translation.y, t.translation.z, t.rotation.w] == root[[0, 1, 2, 3]].tolist()


# ----------------------------------------------------------------------------------- writer rules
def test_discarded_and_uncommitted_episodes_are_not_read(tmp_path):
    meta = synthetic_meta()
    eps = [synthetic_episode(meta, i, 6) for i in range(3)]
    w = McapWriter(tmp_path / "s.mcap", meta)
    w.write_episode(eps[0])
    for ep in eps[1:]:
        sink = w.begin_episode(ep.meta, ep.reset_block())
        sink.append(ep.steps_block())
        if ep.meta.index == 1:
            sink.discard()
    w.close()  # episode 2 never committed
    with open_reader(tmp_path / "s.mcap") as r:
        assert [m.index for m in r.episodes] == [0]
        assert r.unfinished == ["episode 2 (env 0, 6 step(s) in the file)"]
        assert_same_episode(r.read_episode(0), eps[0])
        with pytest.raises(RecordingFileError, match="no episode 1"):
            r.read_episode(1)


def test_writer_refuses_bad_blocks_duplicate_indices_and_existing_files(tmp_path):
    meta = synthetic_meta()
    ep = synthetic_episode(meta, 0, 4)
    with McapWriter(tmp_path / "s.mcap", meta) as w:
        w.write_episode(ep)
        with pytest.raises(UsageError, match="episode 0 was already written"):
            w.write_episode(ep)
        bad = synthetic_episode(meta, 1, 4)
        bad.contact_forces = bad.contact_forces[:, :1]
        with pytest.raises(ValueError, match=r"episode 1: contact_forces has shape \(4, 1, 3\), expected \(4, 2, 3\)"):
            w.write_episode(bad)
    with pytest.raises(UsageError, match="already exists; pass --overwrite"):
        McapWriter(tmp_path / "s.mcap", meta)
    with pytest.raises(UsageError, match="unknown MCAP compression 'gzip'"):
        McapWriter(tmp_path / "t.mcap", meta, compression="gzip")


def test_layout_mismatches_are_simreel_errors(tmp_path):
    """Regression: `pack_block` raised a bare ValueError, which the CLI showed as a traceback."""
    meta = synthetic_meta()
    with McapWriter(tmp_path / "s.mcap", meta) as w:
        bad = synthetic_episode(meta, 0, 4)
        bad.contact_forces = bad.contact_forces[:, :1]
        with pytest.raises(EpisodeLayoutError) as err:
            w.write_episode(bad)
        assert isinstance(err.value, SimreelError)
        assert str(err.value) == "episode 0: contact_forces has shape (4, 1, 3), expected (4, 2, 3) from the layout"
        no_poses = synthetic_episode(meta, 1, 4)
        no_poses.body_poses = None
        with pytest.raises(EpisodeLayoutError, match="episode 1: no body_poses to write"):
            w.write_episode(no_poses)


def test_a_failing_writer_constructor_closes_and_removes_its_file(tmp_path, monkeypatch):
    """Regression: a failure after `open` leaked the handle and left a truncated file."""
    handles = []

    def boom(self):
        handles.append(self._fh)
        raise RuntimeError("boom")

    from simreel.formats.mcap.channels import McapChannels

    monkeypatch.setattr(McapChannels, "_register", boom)
    path = tmp_path / "s.mcap"
    with pytest.raises(RuntimeError, match="boom"):
        McapWriter(path, synthetic_meta())
    assert handles[0].closed and not path.exists()
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="boom"):
        McapWriter(path, synthetic_meta(), overwrite=True)
    # the recording that was to replace it is dropped; the old file is kept as it was
    assert handles[1].closed and path.read_bytes() == b"old" and sorted(tmp_path.iterdir()) == [path]


def test_overwrite_never_truncates_a_file_another_writer_holds(tmp_path, monkeypatch):
    """Even when the `being_written` probe misses it (a race), the lock is taken before the file is emptied."""
    import simreel.formats.base as base_module

    meta = synthetic_meta()
    path = tmp_path / "live.mcap"
    with McapWriter(path, meta) as w:
        w.write_episode(synthetic_episode(meta, 0, 3))
        size = path.stat().st_size
        monkeypatch.setattr(base_module, "being_written", lambda p: False)
        with pytest.raises(UsageError, match="is being written by another recording"):
            McapWriter(path, meta, overwrite=True)
        assert path.stat().st_size == size
    with open_reader(path) as r:
        assert len(r) == 1


def test_parallel_envs_get_their_own_frames_and_time_lanes(tmp_path):
    meta = synthetic_meta()
    meta.num_envs = 2
    episodes = [synthetic_episode(meta, i, T) for i, T in enumerate((3, 5, 2))]
    for ep, env in zip(episodes, (0, 1, 0), strict=True):
        ep.meta.env_idx = env
    write(tmp_path / "s.mcap", meta, episodes)
    starts = {}
    for _, _, m in messages(tmp_path / "s.mcap", TOPICS["reset"]):
        starts[int.from_bytes(m.data[:4], "little")] = m.log_time - time_origin(tmp_path / "s.mcap")
    assert starts == {0: 0, 1: 0, 2: 4 * 50_000_000}  # env 0: episode 2 follows episode 0's 4 rows
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf import FrameTransforms_pb2

    children = {t.child_frame_id for _, _, m in messages(tmp_path / "s.mcap", TOPICS["tf"])
                for t in FrameTransforms_pb2.FrameTransforms.FromString(m.data).transforms}
    assert children == {f"env{e}/{b}" for e in (0, 1) for b in meta.pose_bodies}
    with open_reader(tmp_path / "s.mcap") as r:
        for want in episodes:
            assert_same_episode(r.read_episode(want.meta.index), want)


def test_a_file_being_written_is_not_mistaken_for_a_killed_one(tmp_path):
    meta = synthetic_meta()
    path = tmp_path / "live.mcap"
    with McapWriter(path, meta) as w:
        w.write_episode(synthetic_episode(meta, 0, 3))
        for attempt in (lambda: open_reader(path), lambda: recover(path)):
            with pytest.raises(RecordingFileError, match="still being written by a running recording"):
                attempt()
        with pytest.raises(UsageError, match="is being written by another recording"):
            McapWriter(path, meta, overwrite=True)
    with open_reader(path) as r:
        assert len(r) == 1


# ----------------------------------------------------------------------------------- bad input
def _truncated(tmp_path: Path) -> Path:
    meta = synthetic_meta()
    good = write(tmp_path / "good.mcap", meta, [synthetic_episode(meta, i, 30) for i in range(3)])
    data = good.read_bytes()
    (tmp_path / "bad.mcap").write_bytes(data[: len(data) * 2 // 3])
    return tmp_path / "bad.mcap"


def _foreign(tmp_path: Path) -> Path:
    from mcap.writer import Writer

    with open(tmp_path / "bad.mcap", "wb") as fh:
        w = Writer(fh)
        w.start()
        channel = w.register_channel("/chatter", "json", w.register_schema("Msg", "jsonschema", b"{}"))
        w.add_message(channel, 0, b'{"a": 1}', 0)
        w.add_metadata("other", {"k": "v"})
        w.finish()
    return tmp_path / "bad.mcap"


def _magic_only(tmp_path: Path) -> Path:
    (tmp_path / "bad.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x01" * 5)
    return tmp_path / "bad.mcap"


def _not_mcap(tmp_path: Path) -> Path:
    (tmp_path / "bad.mcap").write_bytes(b"hello, this is not a recording\n")
    return tmp_path / "bad.mcap"


@pytest.mark.parametrize(
    ("make_bad", "problem"),
    [
        (_truncated, "truncated MCAP file (no footer): the recording was interrupted or the file was cut; "
                     "run `simreel recover"),
        (_foreign, "an MCAP file without simreel metadata (not recorded by simreel)"),
        (_magic_only, "truncated MCAP file (no footer)"),
        (_not_mcap, "neither an HDF5 nor an MCAP file"),
    ],
)
def test_bad_files_are_one_line_and_exit_2(tmp_path, make_bad, problem):
    bad = make_bad(tmp_path)
    with pytest.raises(RecordingFileError) as err:
        open_reader(bad)
    assert problem in str(err.value)
    proc = simreel_cli("inspect", str(bad))
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith(f"simreel inspect: error: {bad}: "), proc.stderr
    assert problem in proc.stderr


def test_recover_refuses_foreign_and_keeps_complete_files(tmp_path):
    with pytest.raises(RecordingFileError, match="without simreel metadata"):
        recover(_foreign(tmp_path))
    meta = synthetic_meta()
    good = write(tmp_path / "good.mcap", meta, [synthetic_episode(meta, 0, 3)])
    before = good.read_bytes()
    assert recover(good).complete and good.read_bytes() == before


def test_recover_of_a_cut_file_keeps_the_committed_episodes(tmp_path):
    bad = _truncated(tmp_path)
    report = recover(bad)
    assert report.output == str(bad) and report.lost_bytes > 0
    meta = synthetic_meta()
    with open_reader(bad) as r:
        assert 1 <= len(r.episodes) < 3
        for m in r.episodes:
            assert_same_episode(r.read_episode(m.index), synthetic_episode(meta, m.index, 30))


def test_recover_o_keeps_an_output_it_refuses(tmp_path, capsys):
    """Regression: `recover PATH -o OUT` deleted an existing OUT after refusing to overwrite it."""
    from simreel.cli.main import main

    bad = _truncated(tmp_path)
    cut = bad.read_bytes()
    keep = tmp_path / "keep.mcap"
    keep.write_text("x\n")
    assert main(["recover", str(bad), "-o", str(keep)]) == 2
    err = capsys.readouterr().err
    assert err == f"simreel recover: error: {keep} already exists; pass --overwrite to replace it (overwrite=True from Python)\n"
    assert keep.read_text() == "x\n" and bad.read_bytes() == cut
    meta = synthetic_meta()
    live = tmp_path / "live.mcap"
    with McapWriter(live, meta) as w:  # OUT being written by another recording: refused, left alone
        w.write_episode(synthetic_episode(meta, 0, 3))
        with pytest.raises(UsageError, match="is being written by another recording"):
            recover(bad, live, overwrite=True)
    with open_reader(live) as r:
        assert len(r) == 1
    assert recover(bad, keep, overwrite=True).output == str(keep)
    with open_reader(keep) as r:
        assert 1 <= len(r) < 3


def test_recover_o_with_an_h5_suffix_writes_hdf5(tmp_path):
    report = recover(_truncated(tmp_path), tmp_path / "out.h5")
    with open(tmp_path / "out.h5", "rb") as fh:
        assert fh.read(4) == b"\x89HDF"
    with open_reader(tmp_path / "out.h5") as r:
        assert len(r) == report.episodes >= 1


# ----------------------------------------------------------------------------------- kill -9
def test_kill_9_then_recover_keeps_every_committed_episode(tmp_path, monkeypatch, capsys):
    out = tmp_path / "killed.mcap"
    child = subprocess.Popen([sys.executable, str(SUPPORT / "mcap_kill_child.py"), str(out), "3", "12"],
                             stdout=subprocess.PIPE, text=True)
    try:
        lines = []
        for line in child.stdout:  # the child sleeps after "running" until it is killed
            lines.append(line.strip())
            if line.strip() == "running":
                break
        writers = child_pids(child.pid)
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        child.wait(timeout=60)
    assert lines == ["committed 3", "running"] and child.returncode == -signal.SIGKILL
    wait_ended(writers)  # the writer process ends with its recorder, leaving the file as the kill found it

    with pytest.raises(RecordingFileError, match="run `simreel recover"):
        open_reader(out)
    from simreel.cli import main as cli_main

    if "recover" not in cli_main.COMMANDS:
        monkeypatch.setattr(cli_main, "COMMANDS", (*cli_main.COMMANDS, "recover"))
    assert cli_main.main(["recover", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "recovered 3 committed episode(s), 36 steps" in printed
    assert "lost (never committed): episode 3 (env 0, " in printed  # the running one, with its steps on disk

    from support.mcap_kill_child import episode_actions

    with open_reader(out) as r:
        assert [(m.index, m.seed, m.length) for m in r.episodes] == [(k, k, 12) for k in range(3)]
        assert r.unfinished == []
        for k in range(3):
            ep = r.read_episode(k)
            np.testing.assert_array_equal(ep.actions, episode_actions(k, 12))
            assert ep.env_states["actors/cube"].shape == (13, 13) and ep.body_poses.shape[0] == 13


@pytest.mark.parametrize("obs_mode", ["state", "rgb"])
def test_convert_with_poses_computes_the_recorded_link_poses(pickcube_h5, tmp_path, obs_mode):
    """An HDF5 file without body poses → MCAP with every link's pose, computed in the rebuilt env, which renders
    nothing whatever the recording's observation mode (before, an rgb recording was refused for want of a render
    device the poses do not need)."""
    with open_reader(pickcube_h5) as r:
        meta, episodes = r.meta, [r.read_episode(m.index) for m in r.episodes]
    recorded = [ep.body_poses for ep in episodes]
    stripped = type(meta).from_json({**meta.to_json(), "pose_bodies": [], "obs_mode": obs_mode})
    for ep in episodes:
        ep.body_poses = None
    write(tmp_path / "no_poses.h5", stripped, episodes)
    from simreel.datasets.poses import LinkPoses

    convert(tmp_path / "no_poses.h5", tmp_path / "poses.mcap", transform=LinkPoses)
    with open_reader(tmp_path / "poses.mcap") as r:
        assert r.meta.pose_bodies == meta.pose_bodies
        for m, want in zip(r.episodes, recorded, strict=True):
            np.testing.assert_allclose(r.read_episode(m.index).body_poses, want, atol=1e-6)


def test_convert_with_poses_streams_an_episode_of_many_blocks(pickcube_h5, tmp_path):
    """`convert --poses` adds the poses a block of rows at a time: a real 30-step PickCube episode repeated to
    9,000 steps (three blocks) gets, on every row, the link poses recorded with the state it repeats."""
    from simreel.datasets.poses import LinkPoses
    from simreel.formats.base import block_rows

    with open_reader(pickcube_h5) as r:
        meta, episode = r.meta, r.read_episode(r.episodes[0].index)
    times = -(-9000 // episode.length)
    arrays = {f.name: np.concatenate([a[:1], np.tile(a[1:], (times,) + (1,) * (a.ndim - 1))]) if f.per_state
              else np.tile(a, (times,) + (1,) * (a.ndim - 1))
              for f in episode_fields(meta) if (a := episode.fields().get(f.name)) is not None}
    recorded = arrays.pop("body_poses")
    long = Episode.from_fields(dataclasses.replace(episode.meta, length=episode.length * times), arrays)
    stripped = type(meta).from_json({**meta.to_json(), "pose_bodies": []})
    write(tmp_path / "long.h5", stripped, [long])
    with open_reader(tmp_path / "long.h5") as r:
        assert 2 * block_rows(r.open_episode(long.meta.index).fields) < long.length

    convert(tmp_path / "long.h5", tmp_path / "poses.mcap", transform=LinkPoses)
    with open_reader(tmp_path / "poses.mcap") as r:
        got = r.read_episode(long.meta.index)
    assert got.body_poses.shape == recorded.shape
    np.testing.assert_allclose(got.body_poses, recorded, atol=1e-6)
    np.testing.assert_array_equal(got.env_states["actors/cube"], long.env_states["actors/cube"])


def test_steps_asked_for_in_order_read_each_chunk_once(tmp_path, monkeypatch):
    """`McapRows.steps` block after block reads the episode's chunks once, as `blocks()` does (it used to scan
    from the episode's start on every call); steps asked for again, or out of order, are the same rows."""
    import simreel.formats.mcap.reader as mcap_reader

    path, episodes = long_sample(tmp_path / "long.mcap")
    want = episodes[1]
    reads = []
    real = mcap_reader._read_chunk
    monkeypatch.setattr(mcap_reader, "_read_chunk", lambda fh, offset: reads.append(offset) or real(fh, offset))
    with open_reader(path) as r:
        rows = r.open_episode(1)
        for _ in rows.blocks(700):
            pass
        by_blocks = len(reads)
        reads.clear()
        got = [rows.steps(start, min(start + 700, want.length)) for start in range(0, want.length, 700)]
        assert len(reads) == by_blocks
        np.testing.assert_array_equal(np.concatenate([b["actions"] for b in got]), want.actions)
        np.testing.assert_array_equal(np.concatenate([b["env_states/actors/cube"] for b in got]),
                                      want.env_states["actors/cube"][1:])
        for start, stop in ((8990, 9000), (10, 20), (15, 4000), (0, 1)):
            np.testing.assert_array_equal(rows.steps(start, stop)["actions"], want.actions[start:stop])
