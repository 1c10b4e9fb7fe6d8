"""Builds a `RecordingMeta` from a live env: everything needed to rebuild it and to judge a replay."""

from __future__ import annotations

import dataclasses
import datetime
from typing import Any

from simreel.episode import ContactChannel, RecordingMeta
from simreel.scene_info import describe_scene
from simreel.state_tree import LeafSpec, flatten, layout_of

__all__ = ["recording_meta", "max_episode_steps_of", "MAKE_KWARGS_IN_META", "flatten_obs", "sim_config_json"]

MAKE_KWARGS_IN_META = ("obs_mode", "control_mode", "reward_mode", "sim_backend", "render_backend", "num_envs",
                       "sim_config", "max_episode_steps")
"""gym.make kwargs that RecordingMeta keeps as fields of their own; the rest go to `env_kwargs`."""


def max_episode_steps_of(env: Any) -> int | None:
    """The time limit the wrapper stack enforces (ManiSkill's TimeLimitWrapper or gymnasium's)."""
    e = env
    while e is not None:
        limit = getattr(e, "_max_episode_steps", None)
        if limit is not None:
            return int(limit)
        e = getattr(e, "env", None)
    spec = getattr(env, "spec", None)
    return getattr(spec, "max_episode_steps", None)


def flatten_obs(obs: Any, obs_mode: str) -> dict[str, Any]:
    """Observations as flat key paths; a bare tensor observation is stored under its obs mode's name."""
    if isinstance(obs, dict):
        return flatten(obs)
    return flatten({obs_mode: obs})


def sim_config_json(cfg: Any) -> dict[str, Any]:
    if dataclasses.is_dataclass(cfg):
        return dataclasses.asdict(cfg)
    return dict(cfg or {})


def recording_meta(
    env: Any,
    *,
    contact_channels: list[ContactChannel],
    info_layout: dict[str, LeafSpec],
    obs_layout: dict[str, LeafSpec] | None = None,
    imports: list[str] | None = None,
    command: str = "",
) -> RecordingMeta:
    """Describe `env` (a gym.make'd ManiSkill env, possibly wrapped) as recording metadata."""
    from simreel.envs import env_versions

    u = env.unwrapped
    spec = getattr(u, "spec", None) or getattr(env, "spec", None)
    make_kwargs = dict(getattr(spec, "kwargs", {}) or {})
    space = u.single_action_space
    if space.shape is None:
        from simreel.errors import UsageError

        raise UsageError(
            f"{spec.id if spec is not None else type(u).__name__} has a {type(space).__name__} action space "
            "(a multi-agent task); simreel records single-agent tasks with Box action spaces for now"
        )
    state = flatten(u.get_state_dict())
    return RecordingMeta(
        env_id=spec.id if spec is not None else type(u).__name__,
        env_kwargs={k: v for k, v in make_kwargs.items() if k not in MAKE_KWARGS_IN_META},
        obs_mode=u.obs_mode,
        control_mode=u.control_mode,
        reward_mode=u.reward_mode,
        sim_backend=u.backend.sim_backend,
        render_backend=u.backend.render_backend,
        num_envs=int(u.num_envs),
        max_episode_steps=max_episode_steps_of(env),
        control_freq=float(u.control_freq),
        sim_freq=float(u.sim_freq),
        sim_config=sim_config_json(u.sim_config),
        action_space={
            "shape": list(space.shape),
            "dtype": str(space.dtype),
            "low": space.low.tolist(),
            "high": space.high.tolist(),
        },
        state_layout=layout_of(state, batched=True),
        obs_layout=obs_layout or {},
        info_layout=info_layout,
        scene=describe_scene(u),
        contact_channels=list(contact_channels),
        versions=env_versions(),
        imports=list(imports or []),
        created_utc=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        command=command,
    )
