"""`LinkPoses`: an episode transform that adds the world pose of every named body to each episode of a copy
(``simreel convert --poses``), from its recorded states restored into a rebuilt env."""

from __future__ import annotations

from typing import Any

from simreel.formats.base import EpisodeRows, PassedRows
from simreel.model.blocks import StepBlock
from simreel.model.fields import episode_fields
from simreel.model.meta import RecordingMeta
from simreel.sim.poses import body_poses_from_states, pose_body_names

__all__ = ["LinkPoses"]

_STATES = "env_states/"


class LinkPoses:
    """An episode transform (`simreel.datasets.copy.EpisodeTransform`) that adds `body_poses` of every registry
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
