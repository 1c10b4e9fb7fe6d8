"""`RecordWrapper`: records a ManiSkill env's episodes, with full state dicts and contacts, to a file.

Every parallel env's episode is its own episode on disk. An episode runs from a reset of its env to
the next reset of that env (a partial reset `options={"env_idx": [...]}` ends only those envs'
episodes) or to `close()`. Steps are buffered in blocks of `block_steps` and streamed to the writer,
so memory does not grow with episode length; a finished episode is committed (durable) at once.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from simreel.body_poses import pose_body_names, sample_body_poses
from simreel.contacts import ContactSampler, contact_channels
from simreel.env_meta import flatten_obs, recording_meta
from simreel.episode import FLAG_FIELDS, EpisodeMeta, json_default
from simreel.errors import SimreelError, UsageError
from simreel.fast_state import FastStateReader
from simreel.formats import StepBlock, open_writer, records_poses_by_default
from simreel.recorders.step_buffer import StepBuffer
from simreel.state_tree import LeafSpec, flatten, layout_differences, layout_of, to_numpy

__all__ = ["RecordWrapper", "StateLayoutChanged"]

_SKIPPED_INFO = ("reconfigure",)


class StateLayoutChanged(SimreelError):
    """The task's state dict changed keys or shapes between episodes, so one file cannot hold both."""


def _scalar_info(info: dict[str, Any], n: int) -> dict[str, np.ndarray]:
    """Info entries that hold one scalar per env, as (n,) arrays; everything else is left out."""
    out = {}
    for key, value in info.items():
        if key in _SKIPPED_INFO or isinstance(value, dict):
            continue
        a = to_numpy(value)
        if a.ndim == 0:
            a = np.broadcast_to(a, (n,))
        if a.shape == (n,) and a.dtype.kind in "biuf":
            out[key] = a
    return out


class RecordWrapper(gym.Wrapper):
    """Records every episode of `env` to `path` (.h5 or .mcap).

    Args:
        env: a `gym.make`'d ManiSkill 3 env (any num_envs, CPU or GPU sim), possibly wrapped.
        path: output file; the suffix picks the format.
        contacts: "auto" (net force on every moving body + the task's or the robot fingers' pairs),
            "none", or explicit pairs "panda/panda_leftfinger:cube,...".
        record_obs: also record observations (T+1 rows per episode).
        poses: also record world poses of every body (needed by MCAP's transform channel; costs about
            as much per step as the state dict). None: the format's default (on for .mcap, off for .h5).
        writer_options: keyword options for the format's writer (e.g. HDF5 `compression`).
        overwrite: replace an existing file instead of refusing.
        block_steps: steps buffered in memory before they are streamed to the file.
        imports: `--import` specs that registered the task, stored so replay can import them again.
        command: the command line, stored for provenance.
    """

    def __init__(
        self,
        env: gym.Env,
        path: str | Path,
        *,
        contacts: str | None = "auto",
        record_obs: bool = False,
        poses: bool | None = None,
        overwrite: bool = False,
        block_steps: int = 256,
        imports: list[str] | tuple[str, ...] = (),
        command: str = "",
        writer_options: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(env)
        if block_steps < 1:
            raise UsageError(f"block_steps must be ≥ 1, got {block_steps}")
        _refuse_reshaping_wrappers(env, record_obs)
        u = env.unwrapped
        self._u = u
        self._n = int(u.num_envs)
        self._record_obs = record_obs
        self._sampler = ContactSampler(contact_channels(u, contacts))
        self._sampler.bind(u)
        self._fast: FastStateReader | None = None
        self._fast_unchecked = False
        self._fast_refuted = False
        info_layout = layout_of(_scalar_info(u.get_info(), self._n), batched=True)
        obs_layout: dict[str, LeafSpec] = {}
        if record_obs:
            obs_layout = layout_of(flatten_obs(u.get_obs(), u.obs_mode), batched=True)
        if poses is None:
            poses = records_poses_by_default(path)
        self.meta = recording_meta(
            env,
            contact_channels=self._sampler.channels,
            info_layout=info_layout,
            obs_layout=obs_layout,
            imports=list(imports),
            command=command,
        )
        if poses:
            self.meta.pose_bodies = pose_body_names(u)
        self._writer = open_writer(path, self.meta, overwrite=overwrite, **(writer_options or {}))
        self._buffer = StepBuffer(block_steps, self._n)
        self._sinks: list[Any] = [None] * self._n
        self._episodes: list[EpisodeMeta | None] = [None] * self._n
        self._open = 0
        # Per-env running counts, vectorised so a step costs the same Python work for any num_envs;
        # folded into each episode's EpisodeMeta when it ends.
        self._lengths = np.zeros(self._n, np.int64)
        self._success = np.zeros(self._n, bool)
        self._ever_success = np.zeros(self._n, bool)
        self._has_success = "success" in self.meta.info_layout
        self._next_index = 0
        self._scene_seed: list[int | None] = [None] * self._n
        self.episodes_committed: list[EpisodeMeta] = []
        self._closed = False

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None) -> Any:
        options = dict(options or {})
        env_idx = options.get("env_idx")
        idxs = list(range(self._n)) if env_idx is None else [int(i) for i in to_numpy(env_idx).reshape(-1)]
        for i in idxs:
            self._finish(i)
        if self._buffer.rows and all(s is None for s in self._sinks):
            self._buffer.rewind()
        obs, info = self.env.reset(seed=seed, options=options or None)
        reconfigured = bool(to_numpy(info.get("reconfigure", False)).any()) if "reconfigure" in info else False
        self._sampler.bind(self._u)
        if not self._fast_refuted:  # a reconfiguring reset builds new bodies: bind a new reader
            self._fast = FastStateReader.for_env(self._u)
            self._fast_unchecked = self._fast is not None
        state = flatten(self._u.get_state_dict())
        self._check_layout(state)
        obs_flat = flatten_obs(obs, self._u.obs_mode) if self._record_obs else {}
        poses = self._poses()
        seeds = self._episode_seeds(seed, idxs)
        stored_options = {k: v for k, v in options.items() if k != "env_idx"}
        stored_options = json.loads(json.dumps(stored_options, default=json_default))
        for i, seed_i in zip(idxs, seeds, strict=True):
            if reconfigured:
                self._scene_seed[i] = seed_i
            meta = EpisodeMeta(
                index=self._next_index,
                seed=seed_i,
                reset_options=stored_options,
                env_idx=i,
                reconfigured=reconfigured,
                scene_seed=self._scene_seed[i],
            )
            self._next_index += 1
            self._episodes[i] = meta
            self._open += 1
            self._lengths[i] = 0
            self._success[i] = self._ever_success[i] = False
            self._sinks[i] = self._writer.begin_episode(
                meta,
                {p: a[i] for p, a in state.items()},
                {p: a[i] for p, a in obs_flat.items()} or None,
                None if poses is None else poses[i],
            )
            self._buffer.start[i] = self._buffer.rows
        return obs, info

    def step(self, action: Any) -> Any:
        if self._open < self._n:
            raise UsageError("RecordWrapper.step() before reset(): reset the env first so the episode has a start")
        obs, reward, terminated, truncated, info = self.env.step(action)
        n = self._n
        fields: dict[str, np.ndarray] = {
            "actions": to_numpy(action).astype(np.float32, copy=False).reshape(n, -1),
            "rewards": to_numpy(reward).astype(np.float32, copy=False).reshape(n),
            "terminated": to_numpy(terminated).reshape(n),
            "truncated": to_numpy(truncated).reshape(n),
        }
        scalars = _scalar_info(info, n)
        for flag in ("success", "fail"):
            fields[flag] = scalars[flag] if flag in scalars else np.zeros(n, bool)
        for key in self.meta.info_layout:
            fields[f"info/{key}"] = scalars[key] if key in scalars else np.zeros(n, self.meta.info_layout[key].dtype)
        for p, a in self._state().items():
            fields[f"env_states/{p}"] = a
        if self._record_obs:
            for p, a in flatten_obs(obs, self._u.obs_mode).items():
                fields[f"obs/{p}"] = a
        if self._sampler.channels:
            fields["contact_forces"] = self._sampler.sample()
        poses = self._poses()
        if poses is not None:
            fields["body_poses"] = poses
        self._buffer.push(fields)
        self._lengths += 1
        self._success[:] = fields["success"]
        self._ever_success |= fields["success"]
        if self._buffer.full:
            for i in range(n):
                self._flush(i)
            self._buffer.rewind()
        return obs, reward, terminated, truncated, info

    def discard_running(self) -> None:
        """Drop the episodes still running (their steps so far are not written); committed ones stay."""
        for i, sink in enumerate(self._sinks):
            if sink is not None:
                sink.discard()
                self._sinks[i] = None
                self._episodes[i] = None
                self._open -= 1
        self._buffer.rewind()

    def close(self) -> None:
        """Commit the running episodes that have at least one step, close the file and the env."""
        if not self._closed:
            self._closed = True
            try:
                for i in range(self._n):
                    self._finish(i)
            finally:
                self._writer.close()
        self.env.close()

    # ------------------------------------------------------------------ internals
    @property
    def path(self) -> Path:
        return self._writer.path

    def _episode_seeds(self, seed: Any, idxs: list[int]) -> list[int | None]:
        """The episode seed of each reset env, or None where the reset was not reproducible from a seed.

        ManiSkill 3.0.1 leaves `_episode_seed` stale after `reset(seed=None)` (the episode is drawn from
        the global RNG instead) and, for a partial reset with a seed list, replaces the whole array by
        that list, one seed per reset env in order.
        """
        u = self._u
        if seed is None and not getattr(u, "_enhanced_determinism", False):
            return [None] * len(idxs)
        drawn = to_numpy(u._episode_seed).reshape(-1)
        if len(drawn) == self._n:
            return [int(drawn[i]) for i in idxs]
        if len(drawn) == len(idxs):
            return [int(x) for x in drawn]
        return [None] * len(idxs)

    def _poses(self) -> np.ndarray | None:
        names = self.meta.pose_bodies
        return sample_body_poses(self._u, names) if names else None

    def _state(self) -> dict[str, np.ndarray]:
        """The state dict after a step; through the fast CPU reader where it is proven equal.

        The reader is checked bit for bit against `get_state_dict()` at the first step of every
        episode (after reset most velocities are zero, a weaker check); any difference retires it.
        """
        if self._fast is None:
            return flatten(self._u.get_state_dict())
        if self._fast_unchecked:
            self._fast_unchecked = False
            if not self._fast.matches():
                self._fast, self._fast_refuted = None, True
                warnings.warn(f"simreel: the fast state reader disagrees with {self.meta.env_id}'s get_state_dict(); "
                              "recording through get_state_dict() from now on", RuntimeWarning, stacklevel=3)
                return flatten(self._u.get_state_dict())
        return self._fast.read()

    def _check_layout(self, state: dict[str, np.ndarray]) -> None:
        layout = layout_of(state, batched=True)
        if layout == self.meta.state_layout:
            return
        diffs = layout_differences(self.meta.state_layout, layout, old_label="first episode", new_label="now")
        raise StateLayoutChanged(
            f"the state dict of {self.meta.env_id} changed after a reset ({'; '.join(diffs[:5])}); one recording "
            "needs one layout — register merged views for per-episode objects (see simreel.heterogeneous)"
        )

    def _flush(self, i: int) -> None:
        sink = self._sinks[i]
        if sink is None or not self._buffer.pending(i):
            return
        rows = self._buffer.take(i)
        sink.append(_block(rows))

    def _finish(self, i: int) -> None:
        sink, meta = self._sinks[i], self._episodes[i]
        if sink is None:
            return
        self._flush(i)
        self._sinks[i] = None
        self._episodes[i] = None
        self._open -= 1
        meta.length = int(self._lengths[i])
        if self._has_success:
            meta.success, meta.ever_success = bool(self._success[i]), bool(self._ever_success[i])
        if meta.length == 0:
            sink.discard()
            return
        sink.commit(meta)
        self.episodes_committed.append(meta)


def _refuse_reshaping_wrappers(env: gym.Env, record_obs: bool) -> None:
    """Actions (and observations, when recorded) must be the task's own: replay feeds them to the task."""
    e = env
    while isinstance(e, gym.Wrapper):
        if isinstance(e, gym.ActionWrapper) or (record_obs and isinstance(e, gym.ObservationWrapper)):
            raise UsageError(
                f"RecordWrapper wraps {type(e).__name__}, which changes the task's "
                f"{'actions' if isinstance(e, gym.ActionWrapper) else 'observations'}; a replay could not "
                "reproduce them. Put RecordWrapper directly around the ManiSkill env, below such wrappers"
            )
        e = e.env


def _block(rows: dict[str, np.ndarray]) -> StepBlock:
    groups: dict[str, dict[str, np.ndarray]] = {"env_states": {}, "obs": {}, "info": {}}
    for name, a in rows.items():
        head, _, rest = name.partition("/")
        if rest:
            groups[head][rest] = a
    return StepBlock(
        actions=rows["actions"],
        rewards=rows["rewards"],
        **{f: rows[f] for f in FLAG_FIELDS},
        env_states=groups["env_states"],
        obs=groups["obs"],
        info=groups["info"],
        contact_forces=rows.get("contact_forces"),
        body_poses=rows.get("body_poses"),
    )
