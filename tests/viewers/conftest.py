"""Fixtures for the viewer tests: a small real recording, a shared rebuilt env, replay-like variants of
it, and an .rrd reader. `.rrd` files are read back with rerun-sdk's own reader (`rerun.chunk.RrdReader`).
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

STEPS = 30
"""Steps of the PickCube recording."""



@dataclasses.dataclass
class RrdContents:
    """What an .rrd holds: `data[entity][column]` → list of (step or None for static, value)."""

    data: dict[str, dict[str, list[tuple[int | None, Any]]]]
    blueprint_views: list[str]
    blueprint_entities: list[str]
    recording_ids: list[str]

    def at(self, entity: str, column: str, step: int | None) -> Any:
        for s, value in self.data[entity][column]:
            if s == step:
                return value
        raise KeyError(f"{entity} {column} has no row at step {step}")

    def steps(self, entity: str, column: str) -> list[int]:
        return [s for s, _ in self.data[entity][column] if s is not None]


def _columns(batch: Any) -> dict[str, list]:
    """A record batch as {column: python list}; time columns as int64 (nanoseconds for log_time/sim_time)."""
    import pyarrow as pa

    out = {}
    for name, column in zip(batch.schema.names, batch.columns, strict=True):
        if pa.types.is_temporal(column.type):
            column = column.cast(pa.int64())
        out[name] = column.to_pylist()
    return out


def read_rrd(path: Path) -> RrdContents:
    import rerun as rr

    reader = rr.chunk.RrdReader(path)
    data: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in reader.store().stream().to_chunks():
        if chunk.entity_path.startswith("/__properties"):
            continue
        rows = _columns(chunk.to_record_batch())
        steps = rows.get("step", [None] * chunk.num_rows)
        for column, values in rows.items():
            if column in ("step", "sim_time") or column.startswith("rerun."):
                continue
            data[chunk.entity_path][column].extend(zip(steps, values, strict=True))
    views, entities = [], []
    for entry in reader.blueprints():
        for chunk in reader.store(store=entry).stream().to_chunks():
            entities.append(chunk.entity_path)
            rows = _columns(chunk.to_record_batch())
            views += [v[0] if isinstance(v, list) else v for v in rows.get("ViewBlueprint:class_identifier", [])]
    return RrdContents({k: dict(v) for k, v in data.items()}, views, entities,
                       [e.recording_id for e in reader.recordings()])


def record_pickcube(path: Path, *, poses: bool) -> None:
    """PickCube with seeded random actions; the cube is lifted 5 cm after the reset, so it falls: its net
    contact force is zero for a few steps, then non-zero once it lands."""
    import sapien
    import torch

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    env = make_env("PickCube-v1", render_backend="none", max_episode_steps=STEPS)
    rec = RecordWrapper(env, path, poses=poses, overwrite=True)
    rec.reset(seed=0)
    u = env.unwrapped
    p = u.cube.pose.p[0].numpy()
    u.cube.set_pose(sapien.Pose(p=[float(p[0]), float(p[1]), float(p[2]) + 0.05]))
    rng = np.random.default_rng(0)
    space = u.single_action_space
    for _ in range(STEPS):
        a = rng.uniform(space.low, space.high).astype(np.float32) * 0.3
        rec.step(torch.from_numpy(a[None]))
    rec.close()


def write_variant(src: Path, dst: Path, *, shift_from: int | None = None, drop_poses: bool = False,
                  camera: bool = False) -> Path:
    """A copy of episode 0 of `src` with the cube moved 5 cm along +y from row `shift_from` on (a replay that
    diverges there), without body poses (the viewer must restore them), and/or with a fake 8×6 rgb camera."""
    from simreel.formats import open_reader, open_writer
    from simreel.state_tree import LeafSpec

    with open_reader(src) as r:
        meta, ep = r.meta, r.read_episode(0)
    states = {k: v.copy() for k, v in ep.env_states.items()}
    if shift_from is not None:
        states["actors/cube"][shift_from:, 1] += 0.05
    obs = dict(ep.obs)
    meta = dataclasses.replace(meta)
    if camera:
        rng = np.random.default_rng(1)
        obs["sensor_data/base_camera/rgb"] = rng.integers(0, 255, (ep.length + 1, 6, 8, 3), dtype=np.uint8)
        obs["sensor_data/base_camera/depth"] = rng.integers(0, 2000, (ep.length + 1, 6, 8, 1), dtype=np.int16)
        meta.obs_layout = {k: LeafSpec(tuple(v.shape[1:]), v.dtype.name) for k, v in obs.items()}
    body_poses = ep.body_poses
    if drop_poses or shift_from is not None:
        body_poses = None
        meta.pose_bodies = []
    variant = dataclasses.replace(ep, env_states=states, obs=obs, body_poses=body_poses)
    with open_writer(dst, meta, overwrite=True) as w:
        w.write_episode(variant)
    return dst


@pytest.fixture(scope="session")
def rrd_reader():
    return read_rrd


@pytest.fixture(scope="session")
def variant():
    """`variant(src, dst, shift_from=, drop_poses=, camera=)`: see `viewer_support.write_variant`."""
    return write_variant


@pytest.fixture(scope="session")
def pickcube_h5(tmp_path_factory) -> Path:
    """30 steps of PickCube-v1 with body poses recorded (see `viewer_support.record_pickcube`)."""
    path = tmp_path_factory.mktemp("rec") / "pickcube.h5"
    record_pickcube(path, poses=True)
    return path


@pytest.fixture(scope="session")
def view_env(pickcube_h5):
    """One PickCube env rebuilt for viewing (collision geometry, no rendering), shared by the tests."""
    from simreel.formats import open_reader
    from simreel.viewers import rebuild_env

    with open_reader(pickcube_h5) as r:
        env = rebuild_env(r.meta, geometry="collision")
    yield env
    env.close()
