"""Rebuild the env a recording was made in, from its `RecordingMeta` alone, and reset it to an episode's scene.

Every room that needs the recorded scene again (replay, convert, view) calls `env_from_meta`; it is the
one place that maps metadata fields back to `simreel.sim.make.make_env` arguments. `reset_to_episode` is the
one place that reproduces an episode's reset (its scene, seed and options) from its `EpisodeMeta`; an episode reset
without a seed is reset with the process's random generators set to the states its reset drew from, where the
recording holds them (`EpisodeMeta.reset_generators`, `simreel.sim.generators`).
mani_skill is imported only when a function runs.

Reproducing a reset: an episode whose reset rebuilt the scene (``reconfigured``) is reset with
``reconfigure=True`` and its own seed. Where that is unknown (``reconfigured`` None: ManiSkill's own files do
not say) the reset is made as given, as ManiSkill's replay_trajectory makes it, on the scene the env holds (rebuilt
first, as ``gym.make`` built it, when that scene is unknown). Otherwise the scene it ran in was built by the reset with
seed ``scene_seed`` (None: the scene ``gym.make`` built, i.e. seed `GYM_MAKE_SEED` + sub-scene index); if the
env's scene came from another seed it is rebuilt first with ``reset(seed=scene_seed,
options={"reconfigure": True})``, then the episode is reset with its seed and options, with ManiSkill's
periodic reconfiguration held off (the recorded reset did not reconfigure).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

from simreel.errors import RenderUnavailableError
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.model.state_tree import to_numpy
from simreel.sim.generators import recorded_generators

if TYPE_CHECKING:
    import gymnasium as gym

__all__ = [
    "GYM_MAKE_SEED",
    "UNSEEDED_WITHOUT_STATES",
    "OTHER_EPISODE_OFFSET",
    "another_episode",
    "EpisodeReset",
    "build_with_render_fallback",
    "env_from_meta",
    "reset_to_episode",
]

GYM_MAKE_SEED = 2022
"""ManiSkill 3.0.1's `gym.make` builds the scene with `reset(seed=[2022 + i for i in range(num_envs)])`."""

_T = TypeVar("_T")

OTHER_EPISODE_OFFSET = 7919
"""`another_episode` resets with the episode's seed + this (this alone for an unseeded episode)."""


def env_from_meta(meta: RecordingMeta, **overrides: Any) -> gym.Env:
    """Import ``meta.imports`` as they are, then `make_env` the recorded env.

    A recording's imports may not be where it says any more (it was moved, or replayed on another machine):
    callers find them first with `simreel.sim.user_code.resolve_task_imports` (the user's ``--import``, else
    the recorded ones, looked for beside the recording too) and pass a copy of `meta` holding what was found,
    ``dataclasses.replace(meta, imports=found)``; replay, view and ``convert --poses`` do.

    `overrides` replace arguments of `simreel.sim.make.EnvConfig.from_meta(meta)` (``num_envs=1``,
    ``obs_mode="state"``, ``render_backend="none"``, ...); an unknown name raises TypeError. Raises
    `simreel.errors.EnvBuildError` / `RenderUnavailableError` as `make_env` does.
    """
    from simreel.sim.make import EnvConfig, make_env

    import_task_code(meta)
    return make_env(meta.env_id, EnvConfig.from_meta(meta), **overrides)


def state_only_kwargs(meta: RecordingMeta) -> dict[str, Any]:
    """The recorded task keyword arguments an env rebuilt only to restore states takes: without ``render_mode``
    (it would need a render device) and ``num_envs`` (such an env has one sub-scene)."""
    return {k: v for k, v in meta.env_kwargs.items() if k not in ("render_mode", "num_envs")}


def import_task_code(meta: RecordingMeta) -> None:
    """Import ``meta.imports`` (the user code registering the recorded task), as `env_from_meta` does first: only
    specs the user gave their word for (`simreel.sim.user_code.refuse_unvetted_imports`)."""
    from simreel.sim.user_code import import_user_code, refuse_unvetted_imports

    refuse_unvetted_imports(meta.imports)
    for spec in meta.imports:
        import_user_code(spec)


def build_with_render_fallback(build: Callable[[str], _T], render_backend: str) -> tuple[_T, str]:
    """`build(render_backend)`, and once more with ``"auto"`` when that was ``"none"`` and the task turned out to
    need a render device even without cameras (PushT-v1 reads render shapes while building its scene).

    Returns what `build` returned and the render backend it was built with. Pass the backend a user asked for
    explicitly to `build` directly instead: this helper only corrects a default.
    """
    try:
        return build(render_backend), render_backend
    except RenderUnavailableError:
        if render_backend != "none":
            raise
        return build("auto"), "auto"


@dataclass
class EpisodeReset:
    """What `reset_to_episode` did."""

    scene_seed: int | None
    """Seed of the scene the env holds now (None: unknown, e.g. a reconfiguring reset without a seed)."""
    scene_builds: int = 0
    """How many times the scene was rebuilt (0, 1 or 2): a rebuilt scene has new bodies."""
    notes: list[str] = field(default_factory=list)
    """What was done, for reports: ``"rebuilt the scene with seed 4"``."""
    limits: list[str] = field(default_factory=list)
    """What could not be reproduced: ``"the episode has no seed: its reset cannot be reproduced"``."""


UNSEEDED_WITHOUT_STATES = ("its reset had no seed and the recording holds no env states, so where it began can be "
                           "neither remade nor restored")
"""Why an episode without a seed cannot be stepped from a recording without states: any start would be another's."""


def reset_to_episode(env: Any, episode: EpisodeMeta, *, scene_seed: int | None = GYM_MAKE_SEED) -> EpisodeReset:
    """Reset `env` (one sub-scene) the way `episode` was reset: its scene, then its seed and options.

    Args:
        env: a (wrapped) ManiSkill env with ``num_envs=1``, e.g. from `env_from_meta`.
        episode: the episode's metadata (seed, reset options, sub-scene index, scene seed).
        scene_seed: seed of the scene `env` holds now: `GYM_MAKE_SEED` for an env fresh from ``gym.make``,
            the returned `EpisodeReset.scene_seed` of the previous call, or None when unknown: the scene is
            then rebuilt (unless the episode's own reset rebuilds it), which also clears its history.
    """
    out = EpisodeReset(scene_seed=scene_seed)
    options = {k: v for k, v in (episode.reset_options or {}).items() if k not in ("env_idx", "reconfigure")}
    if episode.reconfigured is None:
        _reset_as_given(env, episode, options, out)
    elif episode.reconfigured:
        with recorded_generators(episode.reset_generators, env.unwrapped):
            env.reset(seed=episode.seed, options={**options, "reconfigure": True})
        out.scene_seed = episode.seed
        out.scene_builds += 1
    else:
        _reset_in_its_scene(env, episode, options, out)
    if episode.seed is None and not episode.reset_generators:
        out.limits.append("the episode has no seed: its reset cannot be reproduced")
    elif episode.seed is None:
        out.notes.append(f"reset without a seed, its random generators ({', '.join(episode.reset_generators)}) set "
                         "to their recorded states")
    return out


def _reconfigured(info: dict[str, Any]) -> bool:
    return bool(to_numpy(info.get("reconfigure", False)).any())


def _reset_as_given(env: Any, episode: EpisodeMeta, options: dict[str, Any], out: EpisodeReset) -> None:
    """Whether the recorded reset rebuilt the scene is unknown: reset as ManiSkill's replay_trajectory does, on the
    scene the env holds, or, that scene being unknown (``out.scene_seed`` None), on a scene rebuilt first as
    ``gym.make`` built the recorder's (its scene seed, else `GYM_MAKE_SEED` + sub-scene index)."""
    if out.scene_seed is None:
        _rebuild_scene(env, episode, out)
    with recorded_generators(episode.reset_generators, env.unwrapped):
        _, info = env.reset(seed=episode.seed, options=options or None)
    if _reconfigured(info):
        out.scene_seed = episode.seed
        out.scene_builds += 1


def _reset_in_its_scene(env: Any, episode: EpisodeMeta, options: dict[str, Any], out: EpisodeReset) -> None:
    """The recorded reset kept its scene: get that scene back first, then reset without rebuilding it."""
    u = env.unwrapped
    if _scene_seed_of(episode) != out.scene_seed:
        _rebuild_scene(env, episode, out)
    if getattr(u, "reconfiguration_freq", 0) and getattr(u, "_reconfig_counter", 1) == 0:
        u._reconfig_counter = 1  # the recorded reset did not reconfigure; hold ManiSkill's periodic one off
    with recorded_generators(episode.reset_generators, env.unwrapped):
        _, info = env.reset(seed=episode.seed, options=options or None)
    if _reconfigured(info):
        out.scene_seed = episode.seed
        out.scene_builds += 1
        out.limits.append("the reset reconfigured the scene, the recorded one did not")


def _scene_seed_of(episode: EpisodeMeta) -> int:
    """Seed of the reset that built the scene `episode` ran in, when its own reset kept it."""
    return episode.scene_seed if episode.scene_seed is not None else GYM_MAKE_SEED + int(episode.env_idx)


def _rebuild_scene(env: Any, episode: EpisodeMeta, out: EpisodeReset) -> None:
    """Rebuild the scene `episode` ran in (a reconfiguring reset with its seed): bit for bit the scene of an env
    fresh from ``gym.make``, with no history (PhysX's CPU results depend on what a scene ran since it was built)."""
    wanted = _scene_seed_of(episode)
    env.reset(seed=wanted, options={"reconfigure": True})
    out.scene_seed = wanted
    out.scene_builds += 1
    out.notes.append(f"rebuilt the scene with seed {wanted}")


def another_episode(episode: EpisodeMeta) -> EpisodeMeta | None:
    """The metadata of another episode in `episode`'s scene: its scene kept (rebuilt from its seed if needed), its
    reset moved to seed + `OTHER_EPISODE_OFFSET`, so whatever a task draws per episode differs. Restoring a state
    into an env reset to it shows what the state dict misses (the audit and `simreel replay`'s explanations do).
    None when the scene cannot be rebuilt (it was built by a reset without a seed) or the file does not say whether
    the episode's reset rebuilt it."""
    if episode.reconfigured is None or (episode.reconfigured and episode.seed is None):
        return None  # unknown whether the reset rebuilt the scene (ManiSkill's files), or it was built unseeded
    scene_seed = episode.seed if episode.reconfigured else episode.scene_seed
    return dataclasses.replace(episode, seed=(episode.seed or 0) + OTHER_EPISODE_OFFSET, reconfigured=False,
                               scene_seed=scene_seed, reset_generators={})
