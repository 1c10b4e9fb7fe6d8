"""`EnvConfig`: the ``gym.make`` arguments of a ManiSkill env, as `simreel.sim.make.make_env` takes them and a
recording keeps them."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from simreel.model.meta import RecordingMeta

__all__ = ["EnvConfig"]


@dataclass(frozen=True)
class EnvConfig:
    """The ``gym.make`` arguments of a ManiSkill env, as `make_env` takes them and `RecordingMeta` keeps them.

    Attributes:
        num_envs: parallel envs; more than 1 needs the GPU sim (ManiSkill's ``sim_backend="auto"`` picks it).
        obs_mode: ManiSkill observation mode. ``"state"``/``"state_dict"``/``"none"`` need no render device;
            ``rgb``, ``depth``, ``rgbd``, ``pointcloud``, ``sensor_data``, ``segmentation`` (and ``+`` mixes) do.
        control_mode, reward_mode: ManiSkill's; None means the task's default.
        sim_backend: ``"auto"``, ``"cpu"``/``"physx_cpu"`` or ``"gpu"``/``"physx_cuda"``, passed to ManiSkill.
        render_backend: ``"auto"`` (probe: `simreel.sim.render_device.detect_render_backend`), ``"gpu"``,
            ``"cpu"`` (software Vulkan) or ``"none"`` (state-only; `simreel.sim.norender` is switched on).
        env_kwargs: further keyword arguments for the task, e.g. ``{"render_mode": "rgb_array"}``,
            ``{"robot_uids": "panda"}``. One of the named arguments here is taken as that argument (`make_env`),
            unless both give it, differently.
        max_episode_steps: override the task's time limit (None: the task's own).
        sim_config: ManiSkill ``SimConfig`` overrides as a dict, e.g. ``{"sim_freq": 500}``.
    """

    num_envs: int = 1
    obs_mode: str = "state"
    control_mode: str | None = None
    reward_mode: str | None = None
    sim_backend: str = "auto"
    render_backend: str = "auto"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    max_episode_steps: int | None = None
    sim_config: dict[str, Any] | None = None

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The argument names, in order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_meta(cls, meta: RecordingMeta) -> EnvConfig:
        """The config that rebuilds `meta`'s env. The recorded render backend is not reused (it names the
        recording machine's device): the default is ``"auto"``."""
        return cls(
            num_envs=meta.num_envs,
            obs_mode=meta.obs_mode,
            control_mode=meta.control_mode,
            reward_mode=meta.reward_mode,
            sim_backend=meta.sim_backend or "auto",
            env_kwargs=dict(meta.env_kwargs),
            max_episode_steps=meta.max_episode_steps,
            sim_config=dict(meta.sim_config) or None,
        )

    def with_overrides(self, **overrides: Any) -> EnvConfig:
        """This config with some arguments replaced; an unknown name raises TypeError naming the known ones."""
        unknown = sorted(set(overrides) - set(self.names()))
        if unknown:
            raise TypeError(f"unknown env arguments {unknown}; known: {', '.join(self.names())}")
        return dataclasses.replace(self, **overrides)
