"""Scenes whose objects differ per episode: merged actors and articulations are drawn from the right part."""

from __future__ import annotations

import numpy as np
import pytest

from simreel.viewers import build_session

_KIND_TO_SHAPE = {"box": "box", "cylinder": "cylinder", "capsule": "capsule"}


def _record(path, env_id, seeds, steps=4, **make_kwargs):
    """Record one short episode per seed with random actions; return what each episode's scene held, live."""
    import torch

    import simreel.tasks  # noqa: F401  (registers the example tasks)
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    env = make_env(env_id, render_backend="none", **make_kwargs)
    rec = RecordWrapper(env, path, poses=False, imports=["simreel.tasks"])
    u = env.unwrapped
    rng = np.random.default_rng(0)
    live = []
    for seed in seeds:
        rec.reset(seed=seed)
        kinds = getattr(u, "object_kinds", None)
        live.append(kinds() if kinds else [s.joints for s in getattr(u, "cabinet_specs", [])])
        for _ in range(steps):
            a = rng.uniform(-0.2, 0.2, u.single_action_space.shape).astype(np.float32)
            rec.step(torch.from_numpy(a[None]))
    rec.close()
    return live


def test_hetero_pick_draws_each_episodes_own_object(tmp_path, rrd_reader):
    path = tmp_path / "pick.h5"
    kinds = _record(path, "SimreelHeteroPick-v1", seeds=[0, 1, 5])  # box, cylinder, hull
    assert [k[0] for k in kinds] == ["box", "cylinder", "hull"]
    for index, (kind,) in enumerate(kinds):
        with build_session(path, episode=index, geometry="collision") as session:
            geo = {g.name: g for g in session.geometry}["object"]
            if kind == "hull":
                assert not geo.primitives and len(geo.meshes) == 1
            else:
                assert [p.kind for p in geo.primitives] == [_KIND_TO_SHAPE[kind]]
            if index == 1:
                out = session.save(tmp_path / "pick.rrd")
    rrd = rrd_reader(out)
    assert "Cylinders3D:lengths" in rrd.data["/world/object"]
    assert rrd.steps("/world/object", "Transform3D:translation") == list(range(-1, 4))


def test_hetero_drawer_draws_links_only_its_part_has(tmp_path, rrd_reader):
    path = tmp_path / "drawer.h5"
    joints = _record(path, "SimreelHeteroDrawer-v1", seeds=[1])  # a drawer and a knob
    assert joints == [[("drawer", "knob")]]
    with build_session(path, geometry="collision") as session:
        extra = [b.name for b in session.bodies if not b.in_registry]
        assert extra == ["cabinet/knob_1"]  # not in the merged view's links, still drawn
        out = session.save(tmp_path / "drawer.rrd")
    rrd = rrd_reader(out)
    for link in ("body", "handle", "knob_1"):
        assert f"/world/cabinet/{link}" in rrd.data
    # the drawer opens along the recorded qpos: the handle's restored pose follows the joint
    names = rrd.at("/plots/qpos/cabinet", "SeriesLines:names", None)
    assert names[:2] == ["handle", "knob_1"]


@pytest.mark.parametrize("env_id", ["PegInsertionSide-v1"])
def test_builtin_merged_views(tmp_path, env_id):
    path = tmp_path / "peg.h5"
    _record(path, env_id, seeds=[3], steps=2)
    with build_session(path, geometry="collision") as session:
        geo = {g.name: g for g in session.geometry}
        assert not geo["peg"].empty and not geo["box_with_hole"].empty
        assert {"peg", "box_with_hole"} <= {b.name for b in session.bodies if b.in_registry}


def test_an_episode_of_another_sub_scene_is_drawn_in_its_own_scene(tmp_path):
    """An episode whose reset did not rebuild the scene ran in the scene gym.make built: for sub-scene k of a
    batched recording, with seed 2022 + k (HeteroPick: a cylinder in sub-scene 0, a hull in 1). The viewer
    rebuilds that scene, as replay does."""
    import dataclasses

    from simreel.formats import open_reader, open_writer

    path = tmp_path / "pick.h5"
    _record(path, "SimreelHeteroPick-v1", seeds=[0], steps=2)
    with open_reader(path) as r:
        meta, ep = r.meta, r.read_episode(0)
    for env_idx, kind in ((0, "cylinder"), (1, "hull")):
        in_make_scene = dataclasses.replace(ep.meta, env_idx=env_idx, reconfigured=False, scene_seed=None)
        file = tmp_path / f"sub_scene_{env_idx}.h5"
        with open_writer(file, meta) as w:
            w.write_episode(dataclasses.replace(ep, meta=in_make_scene))
        with build_session(file, geometry="collision") as session:
            geo = {g.name: g for g in session.geometry}["object"]
            drawn = "hull" if geo.meshes and not geo.primitives else geo.primitives[0].kind
            assert drawn == kind, env_idx
