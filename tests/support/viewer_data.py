"""A small real recording for the viewer tests, and replay-like variants of it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

__all__ = ["STEPS", "record_pickcube", "write_variant"]

STEPS = 30
"""Steps of the PickCube recording."""


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
    from simreel.model.state_tree import LeafSpec

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
