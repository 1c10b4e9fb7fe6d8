"""World poses of every named body (`<actor>`, `<articulation>/<link>`), live or from recorded states.

The state dict holds actor poses but only root pose + joint positions of articulations, so link poses
need the simulator: `sample_body_poses` reads them from a live env (the recorder), and
`body_poses_from_states` restores each recorded state into a rebuilt env and reads them (viewer,
convert). Rows are `[x, y, z, qw, qx, qy, qz]` (SAPIEN's wxyz), float32, per sub-scene frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from simreel.model.state_tree import to_numpy, unflatten
from simreel.sim.describe import named_bodies

__all__ = ["pose_body_names", "sample_body_poses", "body_poses_from_states", "entity_poses"]

_STATES = "env_states/"


def pose_body_names(unwrapped: Any) -> list[str]:
    """Every registry actor (static ones too: they are drawn) and every articulation link."""
    return list(named_bodies(unwrapped))


def sample_body_poses(unwrapped: Any, names: list[str]) -> np.ndarray:
    """(num_envs, B, 7) poses now. Bodies missing from a sub-scene (scene masks) read as NaN."""
    bodies = named_bodies(unwrapped)
    n = int(unwrapped.num_envs)
    if not unwrapped.scene.gpu_sim_enabled:
        out = np.empty((1, len(names), 7), np.float32)
        for j, name in enumerate(names):
            pose = bodies[name]._bodies[0].entity_pose
            out[0, j, :3] = pose.p
            out[0, j, 3:] = pose.q
        return out
    out = np.full((n, len(names), 7), np.nan, np.float32)
    for j, name in enumerate(names):
        obj = bodies[name]
        out[to_numpy(obj._scene_idxs), j] = to_numpy(obj.pose.raw_pose)
    return out


def entity_poses(entities: Sequence[Any]) -> np.ndarray:
    """(B, 7) poses now of sapien entities (CPU sim: their poses are current)."""
    out = np.empty((len(entities), 7), np.float32)
    for j, entity in enumerate(entities):
        pose = entity.pose
        out[j, :3] = pose.p
        out[j, 3:] = pose.q
    return out


def body_poses_from_states(unwrapped: Any, names: list[str], states: Mapping[str, np.ndarray],
                           rows: Iterable[int] | None = None, *, entities: Sequence[Any] | None = None) -> np.ndarray:
    """(R, B, 7) poses after restoring each row of flat `states` (key path → (T+1, ...)) into env 0.

    `entities`: read these sapien entities of sub-scene 0 (one per name, CPU sim only) instead of looking
    `names` up among `scene_info.named_bodies`; the viewer draws bodies that the registry does not name (links
    that only one part of a merged articulation has, actors outside the state dict).
    """
    import torch

    gpu = bool(unwrapped.scene.gpu_sim_enabled)
    if entities is not None and (gpu or len(entities) != len(names)):
        raise ValueError(f"entities= needs the CPU sim and one entity per name ({len(entities)} for {len(names)} names)")
    total = len(next(iter(states.values())))
    rows = list(range(total) if rows is None else rows)
    out = np.empty((len(rows), len(names), 7), np.float32)
    for k, t in enumerate(rows):
        unwrapped.set_state_dict(unflatten({p: torch.from_numpy(np.ascontiguousarray(a[t][None])) for p, a in states.items()}))
        if gpu:
            unwrapped.scene._gpu_apply_all()
            unwrapped.scene.px.gpu_update_articulation_kinematics()
            unwrapped.scene._gpu_fetch_all()
        out[k] = entity_poses(entities) if entities is not None else sample_body_poses(unwrapped, names)[0]
    return out
