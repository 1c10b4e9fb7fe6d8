"""The replay engine: rebuild a recording's env once, reproduce each episode's reset, drive it in one mode.

Modes (see `MODES`):

- ``actions``: reproduce the reset (seed, options, scene), then step the recorded actions. With
  ``resync=K`` the recorded state is restored before every K-th action, so one divergence does not
  poison the rest of a long episode.
- ``states``: restore the recorded state at every step and recompute what depends on it (observations,
  reward, ``evaluate()`` info, flags). Contact-dependent values (``is_grasped``) and contact forces come
  from one step simulated from the restored previous state, as ManiSkill's own state replay does.
- ``step``: for each t, restore state t, step action t, compare with recorded state t+1: the one-step
  error, the purest measure of what the state dict misses.

Reproducing a reset (``EpisodeMeta``: scene, seed, options) is the core's `simreel.sim.rebuild.reset_to_episode`,
and restoring a state is `simreel.sim.state.restore_state`; the viewer and ``simreel convert --poses`` use both.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.episode import FLAG_FIELDS, Episode, EpisodeMeta, RecordingMeta
from simreel.errors import EnvBuildError, ReplayError, SimreelError
from simreel.sim.fingerprint import SceneDifference
from simreel.sim.rebuild import (
    GYM_MAKE_SEED,
    EpisodeReset,
    build_with_render_fallback,
    env_from_meta,
    import_task_code,
    reset_to_episode,
)
from simreel.sim.state import FastStateReader, check_rebuilt_layout, read_state, restore_state, state_row
from simreel.state_tree import to_numpy

__all__ = ["MODES", "EpisodeReplayer", "ReplayerOptions", "ReplayedEpisode", "ReplayError", "GYM_MAKE_SEED"]

MODES = ("actions", "states", "step")
"""Replay modes; ``resync`` is an option of ``actions`` (with its own default tolerances, see
`simreel.compare.TOLERANCE_MODES`)."""


@dataclass(frozen=True)
class ReplayerOptions:
    """How an `EpisodeReplayer` builds and drives its env.

    Attributes:
        obs_mode: observation mode of the replay (None: the recorded one when observations are needed, else
            ``"none"``, which skips computing observations; the physics is the same).
        need_obs: compute and return observations (for comparing recorded ones or writing ``-o``).
        need_rewards: compute rewards. False (the recording holds none and nothing writes the replay) builds the
            env with ``reward_mode="none"`` where the task allows it: rewards are read-only functions of the
            state, so the physics is the same and no reward is computed that nothing could check.
        pose_bodies: also sample the world pose of these bodies after reset and every step (for ``-o``).
        render_backend: None: ``"none"`` unless the observation mode needs cameras, then ``"auto"``.
        sim_backend: None: the recorded one.
        control_mode: None: the recorded one (another one to replay converted actions: `replay_converted`).
        env_kwargs: ``gym.make`` arguments added to the recorded ones (camera size, shader).
    """

    obs_mode: str | None = None
    need_obs: bool = False
    need_rewards: bool = True
    pose_bodies: tuple[str, ...] = ()
    render_backend: str | None = None
    sim_backend: str | None = None
    control_mode: str | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass
class ReplayedEpisode:
    """What one replay produced: the replayed arrays (same layout as the recording) and notes on how."""

    episode: Episode
    notes: list[str] = field(default_factory=list)
    """How it was replayed, and (also in `limits`) what it could not check or reproduce."""
    seconds: float = 0.0
    compare_contacts: bool = True
    limits: list[str] = field(default_factory=list)
    """What was not checked or not reproduced ("contacts not compared: ...", "... has no seed ...")."""
    clipped: list[int] = field(default_factory=list)
    """Steps whose converted action the target mode's limits clipped (`EpisodeReplayer.replay_converted`)."""
    commands: np.ndarray | None = None
    """(T, 2, 7) per step: the tool-centre pose the recorded action commanded, and the one the converted action
    commanded (`EpisodeReplayer.replay_converted`; NaN where unknown)."""
    scene_differences: list[SceneDifference] | None = None
    """Where the replaying scene differs from the episode's recorded scene fingerprint, found at the reset, before
    any step (empty: the same scene; None: not compared, the recording has no fingerprint)."""
    restored_at: list[int] = field(default_factory=list)
    """Steps before which the replay put the recorded state back (``actions`` mode: 0 for an unseeded episode,
    every K-th with ``resync``); a restored state lacks what PhysX keeps between steps."""


def _scalar(x: Any) -> Any:
    """The one value of env 0 in a scalar, (1,) tensor or array (`.item()` is the cheap way for tensors)."""
    if isinstance(x, (bool, int, float)):
        return x
    try:
        return x.item()
    except (AttributeError, ValueError, RuntimeError):
        return to_numpy(x).reshape(-1)[0]


def _flag(info: dict[str, Any], key: str) -> bool:
    return bool(_scalar(info[key])) if key in info else False


GPU_SIM_BACKENDS = ("physx_cuda", "gpu", "cuda")
"""Names of ManiSkill's GPU sim backend as recordings give it."""


def _has_cuda() -> bool:
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - a broken torch install means no CUDA, not a crash
        return False


class EpisodeReplayer:
    """One env rebuilt from `meta` (num_envs=1), replaying that recording's episodes one at a time.

    Args:
        meta: the recording's metadata.
        options: a `ReplayerOptions`; keyword arguments override its fields (``EpisodeReplayer(meta,
            need_obs=True)``).
    """

    def __init__(self, meta: RecordingMeta, options: ReplayerOptions | None = None, **overrides: Any) -> None:
        opts = dataclasses.replace(options or ReplayerOptions(), **overrides)
        self.meta = meta
        self.need_obs = opts.need_obs or opts.obs_mode is not None
        self.pose_bodies = list(opts.pose_bodies)
        self.obs_mode = opts.obs_mode or (meta.obs_mode if self.need_obs else "none")
        self.need_rewards = opts.need_rewards
        self._render_backend = opts.render_backend
        self._sim_backend = opts.sim_backend
        self._control_mode = opts.control_mode
        self._env_kwargs = dict(opts.env_kwargs)
        self.env: Any = None
        self._build()

    # ------------------------------------------------------------------ env
    def _build(self) -> None:
        self.env = self._make_env()
        self.u = self.env.unwrapped
        self._scene_seed: int | None = GYM_MAKE_SEED
        self._layout_checked = False
        self._fast: FastStateReader | None = None
        self._fast_scene = -1
        self._scene_builds = 0
        self._fast_allowed = True
        self._contacts = None
        self._fingerprint: tuple[int, dict[str, Any]] | None = None  # (scene build, fingerprint)
        if self.meta.contact_channels:
            from simreel.sim.contacts import ContactSampler

            self._contacts = ContactSampler(list(self.meta.contact_channels))
        from simreel.sim.describe import max_episode_steps_of

        self.max_episode_steps = max_episode_steps_of(self.env)

    def _make_env(self) -> Any:
        from simreel.sim.make import camera_use

        # render_mode only matters to env.render() (videos), which a replay never calls
        env_kwargs = {k: v for k, v in self.meta.env_kwargs.items() if k != "render_mode"}
        overrides: dict[str, Any] = {"num_envs": 1, "obs_mode": self.obs_mode,
                                     "env_kwargs": {**env_kwargs, **self._env_kwargs}}
        if self._sim_backend is not None:
            overrides["sim_backend"] = self._sim_backend
        if self._control_mode is not None:
            overrides["control_mode"] = self._control_mode
        if not self.need_rewards and self._rewards_optional():
            overrides["reward_mode"] = "none"

        def build(render: str) -> Any:
            return env_from_meta(self.meta, render_backend=render, **overrides)

        try:
            if self._render_backend is not None:
                return build(self._render_backend)
            default = "none" if camera_use(self.obs_mode) is None else "auto"
            return build_with_render_fallback(build, default)[0]
        except EnvBuildError as exc:
            if self._sim_backend is None and self.meta.sim_backend in GPU_SIM_BACKENDS and not _has_cuda():
                raise ReplayError(
                    f"{self.meta.env_id} was recorded on the GPU sim ({self.meta.sim_backend}) and this machine has "
                    "no CUDA device; replay it on the CPU sim with --sim-backend physx_cpu (sim_backend='physx_cpu'). "
                    "The CPU and GPU sims are different engines, so expect within_tolerance or diverged, not exact"
                ) from exc
            raise

    def _rewards_optional(self) -> bool:
        """Whether the recorded task can be built with ``reward_mode="none"``."""
        from simreel.sim.make import reward_modes

        import_task_code(self.meta)
        return "none" in reward_modes(self.meta.env_id)

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None

    def __enter__(self) -> EpisodeReplayer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ reset
    def reset_for(self, ep: EpisodeMeta) -> EpisodeReset:
        """Reset the env the way episode `ep` was reset (scene, seed, options: `simreel.sim.rebuild.reset_to_episode`);
        returns what was done, with this replayer's own limits added (body poses, contacts)."""
        u = self.u
        done = reset_to_episode(self.env, ep, scene_seed=self._scene_seed)
        self._scene_seed = done.scene_seed
        self._scene_builds += done.scene_builds
        if self._fast_allowed:
            if self._fast is None or self._fast_scene != self._scene_builds:  # a rebuilt scene has new bodies
                self._fast = FastStateReader.for_env(u)
                self._fast_scene = self._scene_builds
            # checked bit for bit against get_state_dict() at every episode start (~0.3 ms)
            if self._fast is not None and not self._fast.matches():
                self._fast = None
                self._fast_allowed = False  # this task's state needs get_state_dict(); stop trying
        if self.pose_bodies:
            from simreel.sim.describe import named_bodies

            missing = sorted(set(self.pose_bodies) - set(named_bodies(u)))
            if missing:
                done.limits.append(f"body poses not written: the rebuilt scene has no {', '.join(missing[:3])}")
                self.pose_bodies = []
        if self._contacts is not None:
            try:
                self._contacts.bind(u)
            except KeyError as e:
                done.limits.append(f"contacts not compared: the rebuilt scene has no body {e}")
                self._contacts = None
        return done

    def scene_check(self, ep: EpisodeMeta) -> list[SceneDifference] | None:
        """Every difference between episode `ep`'s recorded scene fingerprint and the scene the env holds now (after
        `reset_for(ep)`); None when the recording has no fingerprint. The live fingerprint is taken once per scene
        build (~3 ms)."""
        from simreel.sim.fingerprint import apply_changes, scene_differences, scene_fingerprint

        if not self.meta.scene_fingerprint:
            return None
        if self._fingerprint is None or self._fingerprint[0] != self._scene_builds:
            self._fingerprint = (self._scene_builds, scene_fingerprint(self.u))
        recorded = apply_changes(self.meta.scene_fingerprint, ep.scene_changes)
        return scene_differences(recorded, self._fingerprint[1])

    def initial_state(self, ep: EpisodeMeta) -> dict[str, np.ndarray]:
        """The state right after resetting the env the way episode `ep` was reset (row 0 of a replay)."""
        self.reset_for(ep)
        return {k: np.array(v) for k, v in self._state().items()}

    # ------------------------------------------------------------------ replay
    def replay(self, episode: Episode, *, mode: str = "actions", resync: int | None = None) -> ReplayedEpisode:
        """Replay `episode` in `mode` and return the replayed arrays (compare them with `simreel.compare`)."""
        if mode not in MODES:
            raise ReplayError(f"unknown replay mode {mode!r}; expected one of {', '.join(MODES)}")
        if resync is not None and (mode != "actions" or resync < 1):
            raise ReplayError(f"resync={resync} needs mode 'actions' and K >= 1")
        start = time.perf_counter()
        try:
            out = self._replay(episode, mode, resync)
        except SimreelError:
            raise
        except Exception as exc:
            if self.obs_mode != "none" or self.need_obs:
                raise
            # A task whose reward or evaluation reads observations cannot run with obs_mode="none": rebuild
            # with the recorded observation mode and replay again (slower, same physics).
            self.close()
            self.obs_mode = self.meta.obs_mode
            self._build()
            out = self._replay(episode, mode, resync)
            out.notes.insert(0, f"replayed with obs_mode={self.obs_mode!r}: the task failed without observations "
                                f"({type(exc).__name__}: {exc})")
        out.compare_contacts = self._contacts is not None
        out.seconds = time.perf_counter() - start
        return out

    def replay_converted(self, episode: Episode, converter: Any) -> ReplayedEpisode:
        """Reproduce `episode`'s reset, then step, for each recorded action, the action `converter` turns it into
        (`simreel.replay.control`: bound to this env after the reset, called with each recorded action, returning
        the target mode's action and whether it was clipped). The replayed episode holds the converted actions;
        its notes say at which steps the target mode's limits clipped them."""
        import torch

        start = time.perf_counter()
        done = self.reset_for(episode.meta)
        self._check_layout()
        converter.bind(self.u)
        buf = self._new(episode)
        buf.actions = np.zeros((episode.length, *self.u.single_action_space.shape), np.float32)
        self._initial(buf)
        clipped = []
        commands = np.full((episode.length, 2, 7), np.nan)
        commanded = getattr(converter, "commanded", lambda: None)  # optional for converters of one's own
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for t in range(episode.length):
                converted = converter(episode.actions[t])
                buf.actions[t] = converted.action
                clipped += [t] if converted.clipped else []
                self._after_step(buf, t, self._step(torch.from_numpy(buf.actions[t]).to(self.u.device)))
                _put(commands[t], getattr(converted, "wanted", None), commanded())
        notes = [*done.notes, *episode.meta.notes, *done.limits]
        if clipped:
            notes.append(f"the {converter.target_mode} action was clipped to its limits at {len(clipped)} step(s) "
                         f"(first: step {clipped[0]}): the recorded target was out of one step's reach; their commands "
                         "are not compared, the trajectory is")
        out = ReplayedEpisode(buf.episode(), notes, limits=[*episode.meta.notes, *done.limits], clipped=clipped,
                              commands=commands)
        out.compare_contacts = self._contacts is not None
        out.seconds = time.perf_counter() - start
        return out

    def _replay(self, episode: Episode, mode: str, resync: int | None) -> ReplayedEpisode:
        done = self.reset_for(episode.meta)
        self._check_layout()
        scene = self.scene_check(episode.meta)
        run = {"actions": self._run_actions, "states": self._run_states, "step": self._run_step}[mode]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # ManiSkill warns on every out-of-bounds action; the recording had them too
            out = run(episode, resync) if mode == "actions" else run(episode)
        if scene is None:
            done.notes.append("scene fingerprint not compared: the file holds none (ManiSkill's own files, and "
                              "simreel's from before it kept one)")
        out.scene_differences = scene
        file_notes = list(episode.meta.notes)  # what the reader found in the file about this episode
        out.notes = done.notes + file_notes + done.limits + out.limits + out.notes
        out.limits = file_notes + done.limits + out.limits
        return out

    def _check_layout(self) -> None:
        if not self._layout_checked and self.meta.state_layout:  # a file without env_states has none to check
            check_rebuilt_layout(self.u, self.meta.env_id, self.meta.state_layout)
            self._layout_checked = True

    # -- collection helpers
    def _state(self) -> dict[str, np.ndarray]:
        if self._fast is not None:
            return self._fast.read()
        return read_state(self.u)

    def _obs(self, obs: Any) -> dict[str, np.ndarray]:
        from simreel.sim.describe import flatten_obs

        return {p: a[0] for p, a in flatten_obs(obs, self.obs_mode).items()}

    def _new(self, episode: Episode) -> _Buffers:
        return _Buffers(episode, self.meta, n_channels=len(self.meta.contact_channels) if self._contacts else 0,
                        n_poses=len(self.pose_bodies))

    def _after_step(self, buf: _Buffers, t: int, outcome: tuple[Any, Any, Any, Any, Any]) -> None:
        """Store step t's outcome ``(obs, reward, terminated, truncated, info)`` and the state after it."""
        obs, reward, terminated, truncated, info = outcome
        buf.rewards[t] = _scalar(reward)
        buf.terminated[t] = _scalar(terminated)
        buf.truncated[t] = _scalar(truncated)
        buf.success[t] = _flag(info, "success")
        buf.fail[t] = _flag(info, "fail")
        for key, dst in buf.info.items():
            value = info.get(key)
            if value is not None:
                dst[t] = _scalar(value)
        if buf.contact_forces is not None:
            buf.contact_forces[t] = self._contacts.sample()[0]
        buf.set_state(t + 1, self._state())
        if self.need_obs and obs is not None:
            buf.set_obs(t + 1, self._obs(obs))
        if buf.body_poses is not None:
            buf.body_poses[t + 1] = self._poses()

    def _poses(self) -> np.ndarray:
        from simreel.sim.poses import sample_body_poses

        return sample_body_poses(self.u, self.pose_bodies)[0]

    def _initial(self, buf: _Buffers) -> None:
        buf.set_state(0, self._state())
        if buf.body_poses is not None:
            buf.body_poses[0] = self._poses()
        if self.need_obs:
            buf.set_obs(0, self._obs(self.u.get_obs()))

    def _actions(self, episode: Episode) -> Any:
        import torch

        return torch.from_numpy(np.ascontiguousarray(episode.actions)).to(self.u.device)

    def _step(self, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        """`unwrapped.step` plus the time limit (what ManiSkill's TimeLimitWrapper adds), without the wrapper stack."""
        obs, reward, terminated, _, info = self.u.step(action)
        limit = self.max_episode_steps
        truncated = limit is not None and self.u._elapsed_steps[0].item() >= limit
        return obs, reward, terminated, truncated, info

    def _run_actions(self, episode: Episode, resync: int | None) -> ReplayedEpisode:
        actions = self._actions(episode)
        buf = self._new(episode)
        limits = []
        if episode.meta.seed is None:
            # An unseeded reset cannot be reproduced (ManiSkill drew it from the global RNG): start the
            # actions from the recorded initial state instead, and say that the reset went unchecked.
            restore_state(self.u, state_row(episode.env_states, 0), elapsed_steps=0)
            limits.append("actions replayed from the recorded initial state")
        self._initial(buf)
        notes = []
        restored = [0] if episode.meta.seed is None else []
        for t in range(episode.length):
            if resync and t and t % resync == 0:
                restore_state(self.u, state_row(episode.env_states, t), elapsed_steps=t)
                restored.append(t)
            self._after_step(buf, t, self._step(actions[t]))
        if resync:
            notes.append(f"restored the recorded state every {resync} steps")
        return ReplayedEpisode(buf.episode(), notes, limits=limits, restored_at=restored)

    def _run_step(self, episode: Episode) -> ReplayedEpisode:
        actions = self._actions(episode)
        buf = self._new(episode)
        self._initial(buf)
        for t in range(episode.length):
            if t or episode.meta.initial_state_known:  # else step 0 starts from the reproduced reset
                restore_state(self.u, state_row(episode.env_states, t), elapsed_steps=t)
            self._after_step(buf, t, self._step(actions[t]))
        return ReplayedEpisode(buf.episode())

    def _run_states(self, episode: Episode) -> ReplayedEpisode:

        u = self.u
        actions = self._actions(episode)
        buf = self._new(episode)
        restore_state(u, state_row(episode.env_states, 0), elapsed_steps=0)
        self._initial(buf)
        for t in range(episode.length):
            restore_state(u, state_row(episode.env_states, t), elapsed_steps=t)
            self._step(actions[t])  # for contacts: one step from the recorded state t
            contacts = self._contacts.sample()[0] if buf.contact_forces is not None else None
            restore_state(u, state_row(episode.env_states, t + 1), elapsed_steps=t + 1)
            info = u.get_info()
            obs = u.get_obs(info, unflattened=True) if self.obs_mode != "none" else {}
            reward = u.get_reward(obs=obs, action=actions[t][None], info=info)
            terminated = _flag(info, "success") or _flag(info, "fail")
            truncated = self.max_episode_steps is not None and t + 1 >= self.max_episode_steps
            self._after_step(buf, t, (None, reward, terminated, truncated, info))
            if contacts is not None:
                buf.contact_forces[t] = contacts
            if self.need_obs:
                buf.set_obs(t + 1, self._obs(u._flatten_raw_obs(obs) if obs else u.get_obs(info)))
        return ReplayedEpisode(buf.episode())


def _put(rows: np.ndarray, *values: np.ndarray | None) -> None:
    for row, value in zip(rows, values, strict=True):
        if value is not None:
            row[:] = value


class _Buffers:
    """Preallocated arrays of one replayed episode, laid out like the recorded one."""

    def __init__(self, episode: Episode, meta: RecordingMeta, *, n_channels: int, n_poses: int = 0) -> None:
        T = episode.length
        self.meta_ep = dataclasses.replace(episode.meta)
        self.actions = episode.actions
        self.rewards = np.zeros(T, np.float32)
        for name in FLAG_FIELDS:
            setattr(self, name, np.zeros(T, bool))
        self.env_states = {p: np.zeros_like(a) for p, a in episode.env_states.items()}
        self.info = {k: np.zeros_like(a) for k, a in episode.info.items()}
        self.contact_forces = np.zeros((T, n_channels, 3), np.float32) if n_channels else None
        self.obs: dict[str, np.ndarray] = {}
        self.body_poses = np.zeros((T + 1, n_poses, 7), np.float32) if n_poses else None
        self.T = T

    def set_state(self, row: int, flat: dict[str, np.ndarray]) -> None:
        for p, dst in self.env_states.items():
            src = flat.get(p)
            if src is not None:
                dst[row] = src[0]

    def set_obs(self, row: int, flat: dict[str, np.ndarray]) -> None:
        for p, a in flat.items():
            dst = self.obs.get(p)
            if dst is None:
                dst = self.obs[p] = np.zeros((self.T + 1, *a.shape), a.dtype)
            dst[row] = a

    def episode(self) -> Episode:
        return Episode(
            meta=self.meta_ep,
            actions=self.actions,
            rewards=self.rewards,
            terminated=self.terminated,
            truncated=self.truncated,
            success=self.success,
            fail=self.fail,
            env_states=self.env_states,
            obs=self.obs,
            info=self.info,
            contact_forces=self.contact_forces,
            body_poses=self.body_poses,
        )
