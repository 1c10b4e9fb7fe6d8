"""What an MCAP recording shows of its scene without simreel: every body's shapes as one `foxglove.SceneUpdate` on
`/scene`, a URDF of them on `/robot_description`, written once per scene, and a time axis at the recording's date.
Checked with Foxglove's own schemas (foxglove-schemas-protobuf) and Rerun's MCAP reader, on a real PickCube-v1
recording and on geometry made by hand."""

from __future__ import annotations

import datetime
import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from support.foxglove import descriptor_set
from support.mcap_samples import assert_same_episode, synthetic_episode, synthetic_meta

from simreel.formats import open_reader
from simreel.formats.mcap import TOPICS, McapWriter
from simreel.formats.mcap.scene import SCENE_UPDATE_SCHEMA, scene_messages
from simreel.model.geometry import BodyGeometry, MeshPart, Primitive, SceneGeometry

RED, GREY = (255, 0, 0, 255), (128, 128, 128, 255)
TURN_Z = (math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))
"""wxyz: +90° about z."""


def _messages(path: Path, topic: str) -> list:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return list(make_reader(fh).iter_messages(topics=[topic], log_time_order=False))


def _scene_update(data: bytes):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    return SceneUpdate.FromString(data)


def _urdf_text(data: bytes) -> str:
    """A ROS 2 std_msgs/msg/String in CDR: 4-byte encapsulation header, uint32 length with the NUL, text, NUL."""
    assert data[:4] == b"\x00\x01\x00\x00"
    n = int.from_bytes(data[4:8], "little")
    assert len(data) == 8 + n and data[-1:] == b"\x00"
    return data[8:-1].decode()


def _xyz(v) -> list[float]:
    return [v.x, v.y, v.z]


def _xyzw(q) -> list[float]:
    return [q.x, q.y, q.z, q.w]


def _rgba(c) -> list[float]:
    return [c.r, c.g, c.b, c.a]


def _hand_made() -> SceneGeometry:
    mesh = MeshPart(np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]], np.float32),
                    np.array([[0, 1, 2], [0, 2, 3]], np.uint32), None, GREY)
    return SceneGeometry(0, "collision", [
        BodyGeometry("cube", [Primitive("box", (0.02, 0.03, 0.04), (0.1, 0, 0, 1, 0, 0, 0), RED)]),
        BodyGeometry("robot/arm", [Primitive("capsule", (0.05, 0.2, 0.0), (0, 0, 0, *TURN_Z), RED),
                                   Primitive("sphere", (0.07, 0.07, 0.07), (0, 0, 0.5, 1, 0, 0, 0), RED)], [mesh]),
        BodyGeometry("robot/base", [Primitive("cylinder", (0.1, 0.3, 0.0), (0, 0, 0, 1, 0, 0, 0), GREY)]),
        BodyGeometry("table", [Primitive("box", (1, 1, 0.1), (0, 0, -0.1, 1, 0, 0, 0), GREY)],
                     world_pose=(2.0, 0.0, 0.0, *TURN_Z)),
        BodyGeometry("goal_site"),  # no shapes
        BodyGeometry("drawer", [Primitive("box", (0.1, 0.1, 0.1), (0, 0, 0, 1, 0, 0, 0), RED)]),  # moves, no frame
    ])


# ----------------------------------------------------------------------------------- the messages, by hand
def test_the_scene_update_schema_is_foxgloves_own():
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    assert SCENE_UPDATE_SCHEMA == ("foxglove.SceneUpdate", descriptor_set(SceneUpdate.DESCRIPTOR))


def test_each_shape_becomes_foxgloves_primitive_in_its_body_frame():
    pytest.importorskip("foxglove_schemas_protobuf")
    messages = scene_messages(_hand_made(), ["cube", "robot/arm", "robot/base", "goal_site"])
    update = _scene_update(messages.scene_update)
    entities = {e.id: e for e in update.entities}
    # a body without shapes and a moving one without a frame are left out; a static one is drawn in the world
    assert list(entities) == list(messages.entity_ids) == ["cube", "robot/arm", "robot/base", "table"]
    assert {e.id: e.frame_id for e in update.entities} == {"cube": "cube", "robot/arm": "robot/arm",
                                                          "robot/base": "robot/base", "table": "world"}
    assert all(e.frame_locked for e in update.entities) and not update.deletions
    cube = entities["cube"].cubes[0]
    assert _xyz(cube.size) == pytest.approx([0.04, 0.06, 0.08]) and _xyz(cube.pose.position) == [0.1, 0, 0]
    assert _rgba(cube.color) == [1, 0, 0, 1]
    arm = entities["robot/arm"]
    # a capsule along local x (turned onto y by its pose): a cylinder along y and a sphere at each end
    cylinder = arm.cylinders[0]
    assert _xyz(cylinder.size) == pytest.approx([0.1, 0.1, 0.4])
    assert (cylinder.bottom_scale, cylinder.top_scale) == (1.0, 1.0)
    from scipy.spatial.transform import Rotation

    axis = Rotation.from_quat(_xyzw(cylinder.pose.orientation)).apply([0, 0, 1])
    np.testing.assert_allclose(np.abs(axis), [0, 1, 0], atol=1e-12)
    ends = sorted(tuple(np.round(_xyz(s.pose.position), 12)) for s in arm.spheres[:2])
    assert ends == [(0.0, -0.2, 0.0), (0.0, 0.2, 0.0)]
    assert _xyz(arm.spheres[2].size) == pytest.approx([0.14] * 3) and _xyz(arm.spheres[2].pose.position) == [0, 0, 0.5]
    triangles = arm.triangles[0]
    assert [_xyz(p) for p in triangles.points] == [[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]]
    assert list(triangles.indices) == [0, 1, 2, 0, 2, 3] and _rgba(triangles.color) == pytest.approx([128 / 255] * 3 + [1])
    # a static body outside the frames: its shapes placed by its world pose
    table = entities["table"].cubes[0]
    np.testing.assert_allclose(_xyz(table.pose.position), [2, 0, -0.1], atol=1e-12)
    np.testing.assert_allclose(_xyzw(table.pose.orientation), [0, 0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-12)


def test_a_new_scene_deletes_the_entities_it_no_longer_has():
    pytest.importorskip("foxglove_schemas_protobuf")
    geometry = _hand_made()
    geometry.bodies = [b for b in geometry.bodies if b.name != "cube"]
    update = _scene_update(scene_messages(geometry, ["robot/arm"], prefix="env1/",
                                          replaced=["env1/cube", "env1/robot/arm"]).scene_update)
    assert [d.id for d in update.deletions] == ["env1/cube"]
    assert [(e.id, e.frame_id) for e in update.entities] == [("env1/robot/arm", "env1/robot/arm"),
                                                             ("env1/table", "world")]


def test_the_urdf_has_a_link_per_framed_body_and_the_static_ones_on_the_world_link():
    urdf = ET.fromstring(scene_messages(_hand_made(), ["cube", "robot/arm", "robot/base"]).urdf)
    links = {link.get("name"): link for link in urdf.iter("link")}
    assert list(links) == ["world", "cube", "robot/arm", "robot/base"]
    assert {(j.get("type"), j.find("parent").get("link"), j.find("child").get("link")) for j in urdf.iter("joint")} == {
        ("floating", "world", name) for name in ("cube", "robot/arm", "robot/base")}
    assert links["cube"].find("visual/geometry/box").get("size") == "0.04 0.06 0.08"
    arm = [v.find("geometry")[0] for v in links["robot/arm"].iter("visual")]
    assert [g.tag for g in arm] == ["cylinder", "sphere", "sphere", "sphere", "box"]  # the mesh: its bounding box
    assert arm[4].get("size") == "1 2 3"
    table = links["world"].find("visual")
    assert table.find("origin").get("xyz") == "2 0 -0.1" and table.find("geometry/box").get("size") == "2 2 0.2"


# ----------------------------------------------------------------------------------- written by the MCAP writer
def test_the_writer_writes_a_scene_as_the_next_episode_begins_and_only_when_it_changed(tmp_path):
    pytest.importorskip("foxglove_schemas_protobuf")
    meta = synthetic_meta()
    path = tmp_path / "s.mcap"
    episodes = [synthetic_episode(meta, i, 3) for i in range(3)]
    changed = _hand_made()
    changed.bodies = changed.bodies[1:]
    with McapWriter(path, meta) as w:
        w.write_scene(_hand_made())
        w.write_episode(episodes[0])
        w.write_scene(_hand_made())  # the same scene again (a reset that rebuilt it as it was): nothing written
        w.write_episode(episodes[1])
        w.write_scene(changed)
        w.write_episode(episodes[2])
    scenes = _messages(path, TOPICS["scene"])
    descriptions = _messages(path, TOPICS["robot_description"])
    begins = [m.log_time for _, _, m in _messages(path, TOPICS["reset"])]
    assert [m.log_time for _, _, m in scenes] == [m.log_time for _, _, m in descriptions] == [begins[0], begins[2]]
    assert [d.id for d in _scene_update(scenes[1][2].data).deletions] == ["cube"]
    assert "robot/arm" in _urdf_text(descriptions[0][2].data)
    assert descriptions[0][0].name == "std_msgs/msg/String" and descriptions[0][1].message_encoding == "cdr"
    with open_reader(path) as r:  # the exact data reads as before
        for want in episodes:
            assert_same_episode(r.read_episode(want.meta.index), want)


def test_parallel_sub_scenes_are_drawn_on_their_own_frames(tmp_path):
    pytest.importorskip("foxglove_schemas_protobuf")
    meta = synthetic_meta()
    meta.num_envs = 2
    episodes = [synthetic_episode(meta, i, 2) for i in range(2)]
    path = tmp_path / "s.mcap"
    with McapWriter(path, meta) as w:
        for env, episode in enumerate(episodes):
            geometry = _hand_made()
            geometry.env_idx = episode.meta.env_idx = env
            w.write_scene(geometry)
            w.write_episode(episode)
    scenes = [_scene_update(m.data) for _, _, m in _messages(path, TOPICS["scene"])]
    assert [[(e.id, e.frame_id) for e in u.entities][:2] for u in scenes] == [
        [(f"env{i}/cube", f"env{i}/cube"), (f"env{i}/robot/arm", f"env{i}/robot/arm")] for i in (0, 1)]
    robots = [ET.fromstring(_urdf_text(m.data)).get("name") for _, _, m in _messages(path, TOPICS["robot_description"])]
    assert robots == ["env0", "env1"]  # Rerun puts each under its own entity path


def test_the_time_axis_starts_when_the_recording_was_made(tmp_path):
    meta = synthetic_meta()
    meta.created_utc = "2026-12-01T08:30:00+00:00"
    path = tmp_path / "s.mcap"
    with McapWriter(path, meta) as w:
        w.write_episode(synthetic_episode(meta, 0, 2))
    start = datetime.datetime(2026, 12, 1, 8, 30, tzinfo=datetime.timezone.utc).timestamp()
    assert [m.log_time for _, _, m in _messages(path, TOPICS["tf"])] == [
        int(start) * 1_000_000_000 + row * 50_000_000 for row in range(3)]


@pytest.fixture
def written_before(tmp_path, monkeypatch) -> Path:
    """A synthetic recording (`synthetic_meta`, episode 0 of 3 steps) as simreel wrote it before MCAP files held
    their scene and a time origin: no `/scene` or `/robot_description` channel, log times from 0 and no
    `time_origin_ns` in its record."""
    from simreel.formats.mcap import channels, records

    to_metadata, register = records.RecordingRecord.to_metadata, channels.McapChannels._register

    def register_without_scene(self):
        real, skipped = self._mcap, {TOPICS["scene"], TOPICS["robot_description"]}

        class WithoutScene:
            def __getattr__(self, name):
                return getattr(real, name)

            def register_channel(self, topic, *args):
                return -1 if topic in skipped else real.register_channel(topic, *args)

        self._mcap = WithoutScene()
        try:
            return register(self)
        finally:
            self._mcap = real

    monkeypatch.setattr(channels.McapChannels, "_register", register_without_scene)
    monkeypatch.setattr(channels, "time_origin_of", lambda meta: 0)
    monkeypatch.setattr(records.RecordingRecord, "to_metadata",
                        lambda self: {k: v for k, v in to_metadata(self).items() if k != "time_origin_ns"})
    path = tmp_path / "before_scene.mcap"
    meta = synthetic_meta()
    with McapWriter(path, meta) as w:
        w.write_episode(synthetic_episode(meta, 0, 3))
    return path


def test_a_file_written_before_scenes_and_time_origins_reads_as_it_did(written_before):
    from mcap.reader import make_reader

    meta = synthetic_meta()
    with open_reader(written_before) as r:
        assert r.meta.env_id == "Synthetic-v0" and [m.index for m in r.episodes] == [0]
        assert_same_episode(r.read_episode(0), synthetic_episode(meta, 0, 3))
    with written_before.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert {c.topic for c in summary.channels.values()} >= {TOPICS["tf"]} and TOPICS["scene"] not in {
        c.topic for c in summary.channels.values()}
    assert min(m.log_time for _, _, m in _messages(written_before, TOPICS["tf"])) == 0  # the 1970 axis those files have


# ----------------------------------------------------------------------------------- a real recording
@pytest.fixture(scope="module")
def pickcube_mcap(tmp_path_factory) -> Path:
    """2 PickCube-v1 episodes × 5 steps, recorded into MCAP by `RecordWrapper` (its writer process: the geometry
    crosses to it), the second reset rebuilding the scene (the same one)."""
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    path = tmp_path_factory.mktemp("scene") / "pickcube.mcap"
    rec = RecordWrapper(make_env("PickCube-v1", render_backend="none"), path)
    rng = np.random.default_rng(0)
    try:
        for k in range(2):
            rec.reset(seed=k, options={"reconfigure": True} if k else None)
            for _ in range(5):
                rec.step(rng.uniform(-1, 1, 8).astype(np.float32))
    finally:
        rec.close()
    return path


def test_a_recording_draws_every_body_with_shapes_on_its_frame_once(pickcube_mcap):
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

    scenes = _messages(pickcube_mcap, TOPICS["scene"])
    assert len(scenes) == 1 and len(_messages(pickcube_mcap, TOPICS["robot_description"])) == 1
    update = _scene_update(scenes[0][2].data)
    tf = _messages(pickcube_mcap, TOPICS["tf"])
    frames = {t.child_frame_id for t in FrameTransforms.FromString(tf[0][2].data).transforms}
    drawn = {e.id: e for e in update.entities}
    assert {e.frame_id for e in update.entities} <= frames
    links = {f"panda/panda_link{i}" for i in range(8)} | {"panda/panda_hand", "panda/panda_leftfinger"}
    assert links | {"cube", "table-workspace", "ground"} <= set(drawn)
    assert all(drawn[name].triangles or drawn[name].cubes for name in links)
    assert _xyz(drawn["cube"].cubes[0].size) == pytest.approx([0.04] * 3)  # PickCube's cube: half size 0.02
    assert scenes[0][2].log_time == tf[0][2].log_time > 1.7e18  # with the first row, at the recording's date


def _rerun_shapes(chunks) -> tuple[dict[str, str], dict[str, str], set[str]]:
    """(entity path → shape archetype, entity path → its coordinate frame, /tf child frames) of Rerun chunks."""
    shapes: dict[str, str] = {}
    frames: dict[str, str] = {}
    tf_children: set[str] = set()
    for chunk in chunks:
        batch = chunk.to_record_batch()
        names = batch.schema.names
        path = str(chunk.entity_path)
        for kind in ("Boxes3D", "Ellipsoids3D", "Cylinders3D"):
            if f"{kind}:half_sizes" in names or f"{kind}:radii" in names:
                shapes[path] = kind
        if "CoordinateFrame:frame" in names:
            frames[path] = batch.column("CoordinateFrame:frame").to_pylist()[0][0]
        if "Transform3D:child_frame" in names:
            tf_children |= {c[0] for c in batch.column("Transform3D:child_frame").to_pylist()}
    return shapes, frames, tf_children


def _assert_drawn_on_tf_frames(chunks) -> None:
    shapes, frames, tf_children = _rerun_shapes(chunks)
    assert len(shapes) >= 20 and set(shapes.values()) == {"Boxes3D"}  # PickCube without render: boxes and hulls
    drawn_frames = {frames[p] for p in shapes}
    assert drawn_frames <= tf_children | {"world"}
    assert {"cube", "panda/panda_link0", "panda/panda_hand", "panda/panda_leftfinger"} <= drawn_frames


def test_rerun_reads_the_recording_as_3d_entities_on_the_tf_frames(pickcube_mcap):
    """Rerun's MCAP reader turns the URDF into shapes whose coordinate frames are the /tf frames, which place them."""
    import rerun.chunk as rc

    _assert_drawn_on_tf_frames(rc.McapReader(pickcube_mcap).stream().to_chunks())


def test_rerun_s_mcap_conversion_keeps_them_in_the_rrd(pickcube_mcap, tmp_path):
    import rerun.chunk as rc

    rerun_cli = Path(sys.executable).with_name("rerun")
    rrd = tmp_path / "pickcube.rrd"
    done = subprocess.run([str(rerun_cli), "mcap", "convert", str(pickcube_mcap), "-o", str(rrd)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    _assert_drawn_on_tf_frames(rc.RrdReader(rrd).stream().to_chunks())
