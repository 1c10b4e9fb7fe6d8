"""Rebuild the env a recording was made in, from its `RecordingMeta` alone.

Every room that needs the recorded scene again (replay, convert, view) calls `env_from_meta`; it is the
one place that maps metadata fields back to `simreel.envs.make_env` arguments. mani_skill is imported only
when the function runs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from simreel.episode import RecordingMeta

if TYPE_CHECKING:
    import gymnasium as gym

__all__ = ["env_from_meta", "make_kwargs_from_meta"]

_MAKE_ENV_ARGS = (
    "num_envs",
    "obs_mode",
    "control_mode",
    "sim_backend",
    "render_backend",
    "reward_mode",
    "env_kwargs",
    "max_episode_steps",
    "sim_config",
)


def make_kwargs_from_meta(meta: RecordingMeta, **overrides: Any) -> dict[str, Any]:
    """The `make_env` keyword arguments that rebuild `meta`'s env, with `overrides` applied.

    Overrides use `make_env`'s names (`num_envs=1`, `obs_mode="state"`, `render_backend="none"`, ...);
    an unknown name raises TypeError. The recorded render backend is not reused by default (it names
    the recording machine's device): the default is ``"auto"``.
    """
    unknown = sorted(set(overrides) - set(_MAKE_ENV_ARGS))
    if unknown:
        raise TypeError(f"env_from_meta() got unknown overrides {unknown}; known: {', '.join(_MAKE_ENV_ARGS)}")
    kwargs: dict[str, Any] = {
        "num_envs": meta.num_envs,
        "obs_mode": meta.obs_mode,
        "control_mode": meta.control_mode,
        "sim_backend": meta.sim_backend or "auto",
        "render_backend": "auto",
        "reward_mode": meta.reward_mode,
        "env_kwargs": dict(meta.env_kwargs),
        "max_episode_steps": meta.max_episode_steps,
        "sim_config": dict(meta.sim_config) or None,
    }
    kwargs.update(overrides)
    return kwargs


def env_from_meta(meta: RecordingMeta, **overrides: Any) -> gym.Env:
    """Import the recording's `--import` specs, then `make_env` the recorded env (see `make_kwargs_from_meta`).

    Raises `simreel.errors.EnvBuildError` / `RenderUnavailableError` as `make_env` does.
    """
    from simreel.envs import import_user_code, make_env

    for spec in meta.imports:
        import_user_code(spec)
    kwargs = make_kwargs_from_meta(meta, **overrides)
    return make_env(meta.env_id, **kwargs)
