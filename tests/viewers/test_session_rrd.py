"""Sessions saved to .rrd and read back with rerun's own reader: paths, poses, contacts, plots, blueprint."""

from __future__ import annotations

import numpy as np
import pytest
from support.viewer_data import STEPS  # the length of the `pickcube_h5` recording

from simreel.formats import open_reader
from simreel.viewers import build_session
from simreel.viewers.log_contacts import FORCE_THRESHOLD_N
from simreel.viewers.poses import wxyz_to_xyzw

DIVERGE_AT = 12
T_ = "Transform3D:translation"
Q_ = "Transform3D:quaternion"


@pytest.fixture(scope="module")
def saved(pickcube_h5, view_env, rrd_reader, tmp_path_factory):
    out = tmp_path_factory.mktemp("rrd") / "pickcube.rrd"
    with build_session(pickcube_h5, env=view_env, geometry="collision", block_steps=7) as session:
        session.save(out)
    with open_reader(pickcube_h5) as r:
        meta, ep = r.meta, r.read_episode(0)
    return session, rrd_reader(out), meta, ep


def test_entity_paths_and_timelines(saved):
    session, rrd, meta, ep = saved
    entities = set(rrd.data)
    for body in ("cube", "goal_site", "table-workspace", "ground", "panda/panda_link0", "panda/panda_hand"):
        assert f"/world/{body}" in entities
    for path in ("/plots/reward", "/plots/success", "/plots/qpos/panda", "/events", "/plots/info/is_grasped"):
        assert path in entities
    assert any(e.startswith("/contacts/net/") for e in entities)
    assert not any(e.startswith("/compared") for e in entities)
    assert rrd.recording_ids == ["pickcube.h5#episode-0"]
    # every step, on both timelines, for a moving body; the static ground has one static pose
    assert rrd.steps("/world/cube", T_) == list(range(-1, STEPS))  # step -1: the state after reset
    assert [s for s, _ in rrd.data["/world/ground"][T_]] == [None]
    names = rrd.at("/plots/qpos/panda", "SeriesLines:names", None)
    assert names[0] == "panda_joint1" and len(names) == 9
    assert session.pose_source == "recorded"


def test_geometry_is_static_and_typed(saved):
    _, rrd, _, _ = saved
    assert rrd.steps("/world/cube", "Boxes3D:half_sizes") == []  # static only
    half = rrd.at("/world/cube", "Boxes3D:half_sizes", None)
    assert np.allclose(half, [[0.02, 0.02, 0.02]])
    assert "Mesh3D:vertex_positions" in rrd.data["/world/panda/panda_link0"]  # convex collision mesh
    ground = np.asarray(rrd.at("/world/ground", "Mesh3D:vertex_positions", None))
    assert ground.shape == (4, 3) and np.ptp(ground[:, 0]) > 2.0  # a finite square for the infinite plane


@pytest.mark.parametrize("row", [0, 7, 13, STEPS])
def test_poses_equal_recorded(saved, row):
    _, rrd, meta, ep = saved
    step = row - 1  # the timeline shows state row r (the outcome of step r - 1) at step r - 1
    for body in ("cube", "panda/panda_hand", "panda/panda_leftfinger"):
        j = meta.pose_bodies.index(body)
        np.testing.assert_array_equal(rrd.at(f"/world/{body}", T_, step)[0], ep.body_poses[row, j, :3])
        np.testing.assert_array_equal(rrd.at(f"/world/{body}", Q_, step)[0], wxyz_to_xyzw(ep.body_poses[row, j, 3:]))


def test_contact_arrows_only_where_force_is_nonzero(saved):
    _, rrd, meta, ep = saved
    mags = np.linalg.norm(ep.contact_forces, axis=-1)
    checked_both = False
    for c, channel in enumerate(meta.contact_channels):
        path = f"/contacts/{channel.kind}/" + "/".join(channel.bodies)
        on = mags[:, c] > FORCE_THRESHOLD_N
        if not on.any():
            assert path not in rrd.data  # a channel that never touches gets no entity at all
            continue
        rows = dict(rrd.data[path]["Arrows3D:vectors"])
        assert sorted(rows) == list(range(STEPS))  # one row per step: arrows appear and disappear
        for t in range(STEPS):
            assert len(rows[t]) == int(on[t]), (path, t)
        checked_both |= bool(on.any() and (~on).any())
    assert checked_both, "the falling cube should give a channel that is both zero and non-zero"


def test_contact_arrow_sits_at_its_body(saved):
    _, rrd, meta, ep = saved
    c = next(i for i, ch in enumerate(meta.contact_channels) if ch.kind == "net" and ch.bodies == ("cube",))
    t = int(np.nonzero(np.linalg.norm(ep.contact_forces[:, c], axis=-1) > 0)[0][-1])
    origin = rrd.at("/contacts/net/cube", "Arrows3D:origins", t)[0]
    np.testing.assert_allclose(origin, ep.body_poses[t + 1, meta.pose_bodies.index("cube"), :3])
    vector = np.asarray(rrd.at("/contacts/net/cube", "Arrows3D:vectors", t)[0])
    assert np.dot(vector, ep.contact_forces[t, c]) > 0  # same direction as the force


def test_plots_are_aligned_with_steps(saved):
    _, rrd, _, ep = saved
    assert rrd.steps("/plots/reward", "Scalars:scalars") == list(range(STEPS))
    np.testing.assert_allclose([v[0] for _, v in rrd.data["/plots/reward"]["Scalars:scalars"]], ep.rewards, rtol=1e-6)
    qpos = rrd.at("/plots/qpos/panda", "Scalars:scalars", 4)
    np.testing.assert_allclose(qpos, ep.env_states["articulations/panda"][5, 13:22], rtol=1e-6)


def test_blueprint_is_present(saved):
    _, rrd, _, _ = saved
    assert {"3D", "TimeSeries", "TextLog"} <= set(rrd.blueprint_views)
    assert "/viewport" in rrd.blueprint_entities


def test_compare_ghost_and_first_divergence(pickcube_h5, view_env, variant, rrd_reader, tmp_path):
    replayed = variant(pickcube_h5, tmp_path / "replayed.h5", shift_from=DIVERGE_AT)  # state rows ≥ 12 moved
    out = tmp_path / "cmp.rrd"
    with build_session(pickcube_h5, env=view_env, compare=replayed, geometry="collision") as session:
        session.save(out)
    d = session.divergence  # simreel.verdicts.compare's: the outcome of step 11 is state row 12
    assert (d.step, d.at, d.key) == (DIVERGE_AT - 1, "step", "env_states/actors/cube[p]")
    assert d.error == pytest.approx(0.05, abs=1e-6)
    rrd = rrd_reader(out)
    assert "/compared/cube" in rrd.data and "/compared/panda/panda_hand" in rrd.data
    ghost = rrd.at("/compared/cube", "Boxes3D:colors", None)
    assert all((c & 0xFF) < 255 for c in ghost)  # translucent (RGBA packed as 0xRRGGBBAA)
    # the ghost's poses come from the replay's states (restored: the copy holds no body poses)
    later, before = DIVERGE_AT + 2, DIVERGE_AT - 2  # timeline steps
    recorded = rrd.at("/world/cube", T_, later)[0]
    np.testing.assert_allclose(rrd.at("/compared/cube", T_, later)[0], np.add(recorded, [0, 0.05, 0]), atol=1e-6)
    np.testing.assert_allclose(rrd.at("/compared/cube", T_, before)[0], rrd.at("/world/cube", T_, before)[0], atol=1e-6)
    err = dict(rrd.data[r"/plots/error/env_states/actors/cube\[p\]"]["Scalars:scalars"])
    assert err[d.step - 1][0] == 0.0 and err[d.step][0] == pytest.approx(0.05, abs=1e-6)
    assert err[d.step][1] == pytest.approx(1e-5)  # the tolerance line (actions mode: pos 1e-5)
    events = [(step, v[0]) for step, v in rrd.data["/events"]["TextLog:text"]]
    assert (d.step, f"replayed.h5 diverges at {d.describe()}") in events  # marked where the ghost parts (a copy, no replay)
    assert d.describe().startswith(f"step {DIVERGE_AT - 1}: env_states/actors/cube[p] off by 0.05")
    assert "TimeSeries" in rrd.blueprint_views


def test_restored_poses_match_states(pickcube_h5, view_env, variant, rrd_reader, tmp_path):
    no_poses = variant(pickcube_h5, tmp_path / "noposes.h5", drop_poses=True, camera=True)
    out = tmp_path / "restored.rrd"
    with build_session(no_poses, env=view_env, geometry="collision") as session:
        session.save(out)
    assert session.pose_source == "restored"
    rrd = rrd_reader(out)
    with open_reader(no_poses) as r:
        ep = r.read_episode(0)
    for row in (0, 9, STEPS):
        cube = ep.env_states["actors/cube"][row]
        np.testing.assert_allclose(rrd.at("/world/cube", T_, row - 1)[0], cube[:3], atol=1e-6)
        q = np.asarray(rrd.at("/world/cube", Q_, row - 1)[0])
        expect = wxyz_to_xyzw(cube[3:7])
        assert min(np.abs(q - expect).max(), np.abs(q + expect).max()) < 1e-6
    # camera images: one per state row, with their format logged once
    assert rrd.steps("/cameras/base_camera/rgb", "Image:buffer") == list(range(-1, STEPS))
    image = np.asarray(rrd.at("/cameras/base_camera/rgb", "Image:buffer", 3)[0], np.uint8)
    np.testing.assert_array_equal(image, ep.obs["sensor_data/base_camera/rgb"][4].reshape(-1))
    assert "/cameras/base_camera/depth" in rrd.data
    assert rrd.blueprint_views.count("2D") == 2  # a 2D view per camera stream under the 3D view


def test_restored_poses_come_from_the_core(pickcube_h5, view_env):
    """The viewer reads its bodies by entity (some have no registry name); registry bodies read the same by name."""
    from simreel.sim.poses import body_poses_from_states
    from simreel.viewers.poses import PoseSource
    from simreel.viewers.scene_geometry import scene_bodies

    with open_reader(pickcube_h5) as r:
        meta, ep = r.meta, r.read_episode(0)
    u = view_env.unwrapped
    bodies = [b for b in scene_bodies(u) if b.in_registry]
    names = [b.name for b in bodies]
    rows = PoseSource(u, bodies, ep.env_states).rows(3, 9)  # no recorded poses given: restored
    np.testing.assert_array_equal(rows, body_poses_from_states(u, names, ep.env_states, range(3, 9)))
    recorded = ep.body_poses[3:9, [meta.pose_bodies.index(n) for n in names]]
    np.testing.assert_allclose(rows[..., :3], recorded[..., :3], atol=1e-6)
    with pytest.raises(ValueError, match="one entity per name"):
        body_poses_from_states(u, names, ep.env_states, [0], entities=[b.entity for b in bodies[:1]])


def test_save_replaces_an_existing_file_only_when_asked(pickcube_h5, view_env, rrd_reader, tmp_path):
    """`ViewSession.save` replaced an existing .rrd by default (overwrite=True), the one simreel API to do so, and
    took any truthy value, ``overwrite="no"`` too, for yes. Now it refuses as every writer does, the file kept."""
    from simreel.errors import UsageError

    out = tmp_path / "kept.rrd"
    out.write_bytes(b"an earlier session")
    with build_session(pickcube_h5, env=view_env, geometry="collision") as session:
        with pytest.raises(UsageError, match=f"^{out} already exists; pass --overwrite to replace it"):
            session.save(out)
        with pytest.raises(UsageError, match="^overwrite='no': give True or False$"):
            session.save(out, overwrite="no")
        assert out.read_bytes() == b"an earlier session"
        assert session.save(out, overwrite=True) == out
    assert rrd_reader(out).recording_ids == ["pickcube.h5#episode-0"]


def test_save_never_writes_over_the_recordings_shown(pickcube_h5, view_env, tmp_path):
    """A link named .rrd that leads to the recording (or the replay) shown: even with overwrite=True it is refused,
    the recording unchanged."""
    from simreel.errors import UsageError

    link = tmp_path / "session.rrd"
    link.symlink_to(pickcube_h5)
    before = pickcube_h5.read_bytes()
    with build_session(pickcube_h5, env=view_env, geometry="collision", compare=pickcube_h5) as session:
        with pytest.raises(UsageError, match=f"^--save {link} is the recording {pickcube_h5}; write it to another"):
            session.save(link, overwrite=True)
    assert pickcube_h5.read_bytes() == before


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"episode": "1"}, "episode='1': give the episode's index, an int (`simreel inspect` lists them)"),
        ({"episode": True}, "episode=True: give the episode's index, an int"),
        ({"block_steps": "5"}, "block_steps must be an int ≥ 1, got '5'"),
        ({"compare": 3}, "3: give a recording's path, a str or Path"),
        ({"imports": 7}, "imports=7: give the .py files or modules that register the task"),
        ({"tolerances": [("pos", 1)]}, "tolerances=[('pos', 1)]: give a dict of tolerance groups and numbers"),
        ({"options": {"episode": 0}}, "options={'episode': 0}: give a ViewOptions, or its fields as keywords"),
        ({"bogus": 1}, "bogus=1: give only the options ViewOptions has: "),  # was: TypeError naming its __init__
    ],
    ids=["episode-str", "episode-bool", "block_steps-str", "compare-int", "imports-int", "tolerances-list",
         "options-dict", "unknown"],
)
def test_options_of_the_wrong_type_are_a_usage_error(pickcube_h5, view_env, options, message):
    """Before: episode="1" was "no episode 1 (episodes: 0)" of a file that has it, episode=True showed episode 1,
    block_steps="5" and compare=3 were TypeErrors, imports=7 too once the env was built; tolerances as a list an
    AttributeError, options as a dict a TypeError from dataclasses.replace."""
    from simreel.errors import UsageError

    with pytest.raises(UsageError) as caught:
        build_session(pickcube_h5, env=view_env, geometry="collision", **options)
    assert str(caught.value) == message or str(caught.value).startswith(message)


def test_one_import_given_as_a_string_is_one_spec():
    """imports="my_tasks" was imported letter by letter ("--import m: no module named 'm'")."""
    from simreel.viewers import ViewOptions
    from simreel.viewers.video import VideoOptions

    assert ViewOptions(imports="my_tasks").imports == ("my_tasks",)
    assert VideoOptions(imports="my_tasks.py").imports == ("my_tasks.py",)
