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

from simreel.episode import RecordingMeta, StepBlock, episode_fields
from simreel.formats.base import EpisodeRows, PassedRows
from simreel.sim.describe import named_bodies
from simreel.state_tree import to_numpy, unflatten

__all__ = ["pose_body_names", "sample_body_poses", "body_poses_from_states", "entity_poses", "LinkPoses"]

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


class LinkPoses:
    """An episode transform (`simreel.formats.copy.EpisodeTransform`) that adds `body_poses` of every registry
    body to each episode, computed by restoring its states into an env rebuilt from the recording's metadata
    (``simreel convert --poses``), a block of rows at a time. The env computes no observations and renders
    nothing (unless the task needs a render device to build its scene), whatever the recording's `obs_mode`."""

    def __init__(self, meta: RecordingMeta) -> None:
        from simreel.sim.rebuild import build_with_render_fallback, env_from_meta, state_only_kwargs

        def build(render: str) -> Any:
            return env_from_meta(meta, num_envs=1, sim_backend="physx_cpu", obs_mode="none", render_backend=render,
                                 env_kwargs=state_only_kwargs(meta))

        self._env = build_with_render_fallback(build, "none")[0]
        self._u = self._env.unwrapped
        self._u.reset(seed=0)
        self._scene_seed: int | None = None
        self.meta = RecordingMeta.from_json(meta.to_json())
        self.meta.pose_bodies = pose_body_names(self._u)

    def __call__(self, rows: EpisodeRows) -> EpisodeRows:
        from simreel.sim.rebuild import reset_to_episode

        # the episode's own scene (objects of heterogeneous tasks); rebuilt only when it changes
        self._scene_seed = reset_to_episode(self._env, rows.meta, scene_seed=self._scene_seed).scene_seed
        return _WithPoses(rows, self)

    def poses_of(self, block: StepBlock) -> StepBlock:
        """`block` with the `body_poses` of its states (replacing any it had)."""
        states = {k[len(_STATES):]: a for k, a in block.arrays.items() if k.startswith(_STATES)}
        poses = body_poses_from_states(self._u, self.meta.pose_bodies, states)
        return StepBlock.of({**block.arrays, "body_poses": poses})

    def close(self) -> None:
        self._env.close()


class _WithPoses(PassedRows):
    """An episode's rows with `body_poses` added to its reset row and to every block, as they are read (the
    episode's scene already set up by `LinkPoses`)."""

    def __init__(self, rows: EpisodeRows, poses: LinkPoses) -> None:
        super().__init__(rows, fields=episode_fields(poses.meta))
        self._poses = poses

    def passed_reset(self, block: StepBlock) -> StepBlock:
        return self._poses.poses_of(block)

    def passed(self, start: int, block: StepBlock) -> StepBlock:
        return self._poses.poses_of(block)
