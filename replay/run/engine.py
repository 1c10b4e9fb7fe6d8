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

The contacts PhysX reports are those of the last step the scene simulated, so observations taken at a reset read
the contacts of the step before it (ManiSkill's ``is_grasping``, in many tasks' observations: 1 at the reset after
a grasping episode). Before a restoring replay, `EpisodeReplayer.rerun_step_before` re-runs that step.

Reproducing a reset (``EpisodeMeta``: scene, seed, options) is the core's `simreel.sim.rebuild.reset_to_episode`,
and restoring a state is `simreel.sim.state.restore_state`; the viewer and ``simreel convert --poses`` use both.

`EpisodeReplayer` is this module's env and replay; its episode starts are `simreel.replay.run.resets`, its steps
`simreel.replay.run.stepping`, the arrays of a block `simreel.replay.run.blocks`, where its rows go
`simreel.replay.run.sinks`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.errors import EnvBuildError, ReplayError, SimreelError, UsageError
from simreel.formats.base import EpisodeRows
from simreel.model.episode import Episode
from simreel.model.meta import RecordingMeta
from simreel.options.checks import options_with
from simreel.replay.run.blocks import RecordedStates, without_nan
from simreel.replay.run.guards import older_objects_unscanned, task_code_errors
from simreel.replay.run.options import MODES
from simreel.replay.run.replayer_options import ReplayerOptions
from simreel.replay.run.resets import EpisodeResets
from simreel.replay.run.sinks import BlockSink, Collected
from simreel.replay.run.stepping import BlockStepping
from simreel.sim.fingerprint import SceneDifference
from simreel.sim.rebuild import (
    GYM_MAKE_SEED,
    build_with_render_fallback,
    env_from_meta,
    import_task_code,
)
from simreel.sim.state import FastStateReader, restore_state

__all__ = ["MODES", "RESTORING_MODES", "EpisodeReplayer", "ReplayedEpisode", "ReplayError",
           "GYM_MAKE_SEED", "GPU_SIM_BACKENDS"]

RESTORING_MODES = ("states", "step")
"""The modes that restore recorded states, so replay no episode's history: they re-run only the last step of the
episode before (`simreel.replay.run.resets.SceneBefore`)."""



@dataclass
class ReplayedEpisode:
    """What one replay produced: the replayed arrays (same layout as the recording; None when they went to a
    `BlockSink` block by block) and notes on how."""

    episode: Episode | None
    notes: list[str] = field(default_factory=list)
    """How it was replayed, and (also in `limits`) what it could not check or reproduce."""
    seconds: float = 0.0
    compare_contacts: bool = True
    limits: list[str] = field(default_factory=list)
    """What was not checked or not reproduced ("contacts not compared: ...", "... has no seed ...")."""
    clipped: list[int] = field(default_factory=list)
    """Steps whose converted action the target mode's limits clipped (`simreel.replay.convert.replayer.ConvertingReplayer`)."""
    commands: np.ndarray | None = None
    """(T, 2, 7) per step: the tool-centre pose the recorded action commanded, and the one the converted action
    commanded (`simreel.replay.convert.replayer.ConvertingReplayer`; NaN where unknown)."""
    scene_differences: list[SceneDifference] | None = None
    """Where the replaying scene differs from the episode's recorded scene fingerprint, found at the reset, before
    any step (empty: the same scene; None: not compared, the recording has no fingerprint)."""
    restored_at: list[int] = field(default_factory=list)
    """Steps before which the replay put the recorded state back (``actions`` mode: 0 for an unseeded episode,
    every K-th with ``resync``); a restored state lacks what PhysX keeps between steps."""


GPU_SIM_BACKENDS = ("physx_cuda", "gpu", "cuda")
"""Names of ManiSkill's GPU sim backend as recordings give it."""


def _has_cuda() -> bool:
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - a broken torch install means no CUDA, not a crash
        return False


class EpisodeReplayer(EpisodeResets, BlockStepping):
    """One env rebuilt from `meta` (num_envs=1), replaying that recording's episodes one at a time.

    Args:
        meta: the recording's metadata.
        options: a `ReplayerOptions`; keyword arguments override its fields (``EpisodeReplayer(meta,
            need_obs=True)``).
    """

    def __init__(self, meta: RecordingMeta, options: ReplayerOptions | None = None, **overrides: Any) -> None:
        if not isinstance(meta, RecordingMeta):  # a path would fail deep in the env's build as an AttributeError
            raise UsageError(f"meta={meta!r}: give the recording's RecordingMeta, e.g. open_reader(path).meta")
        opts = options_with(ReplayerOptions, options, overrides, "EpisodeReplayer(meta, need_obs=True)")
        self.meta = meta
        self.need_obs = opts.need_obs or opts.obs_mode is not None
        self.pose_bodies = list(opts.pose_bodies)
        self.obs_mode = opts.obs_mode or (meta.obs_mode if self.need_obs else "none")
        self.need_rewards = opts.need_rewards
        self._render_backend = opts.render_backend
        self._sim_backend = opts.sim_backend
        self._control_mode = opts.control_mode
        self._env_kwargs = dict(opts.env_kwargs)
        self._options = opts
        self._in_modes: dict[str, EpisodeReplayer | None] = {}
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
        self._stepped = False
        """Whether the scene simulated a step since it was built (it then reports that step's contacts)."""
        self._carried: list[str] = []
        """Limits met at the reset of `rerun_step_before`, for the episode it runs before (`reset_for`)."""
        self._fast_allowed = True
        self._contacts = None
        self._fingerprint: tuple[int, dict[str, Any]] | None = None  # (scene build, fingerprint)
        if self.meta.contact_channels:
            from simreel.sim.contacts import ContactSampler

            self._contacts = ContactSampler(list(self.meta.contact_channels))
        from simreel.sim.describe import max_episode_steps_of

        self.max_episode_steps = max_episode_steps_of(self.env)
        self._check_action_shape()

    def _check_action_shape(self) -> None:
        """`ReplayError` when the recorded actions' shape is not the rebuilt env's (ManiSkill would fail an assertion
        at the first step of every episode): the recording names another control mode than the one that recorded
        the actions, or none (the env's default is built). Not for a replay in another control mode (`convert`)."""
        recorded = self.meta.action_space.get("shape")
        here = tuple(self.u.single_action_space.shape)
        if self._control_mode is not None or recorded is None or tuple(recorded) == here:
            return
        mode = self.u.control_mode
        named = (f"its control mode, {mode}," if self.meta.control_mode else
                 f"it names no control mode, and {self.meta.env_id}'s default, {mode},")
        raise ReplayError(f"{self.meta.env_id}: the recorded actions have shape {tuple(recorded)} a step, but {named} "
                          f"takes actions of shape {here}: the recording must name the control mode that recorded them")

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
            with older_objects_unscanned():
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
        for other in self._in_modes.values():
            if other is not None:
                other.close()
        self._in_modes.clear()
        if self.env is not None:
            with older_objects_unscanned():
                self.env.close()
            self.env = None

    def same_size_control_modes(self) -> list[str]:
        """The robot's control modes other than the replaying one (`u.control_mode`) that take actions of the recorded
        shape: the modes a recording's actions could have been made in, had it named the wrong one."""
        recorded = self.meta.action_space.get("shape")
        agent = getattr(self.u, "agent", None)
        if recorded is None or agent is None:
            return []
        modes = [m for m in getattr(agent, "supported_control_modes", []) if m != self.u.control_mode]
        return [m for m in modes if self.in_control_mode(m) is not None]

    def in_control_mode(self, mode: str) -> EpisodeReplayer | None:
        """A replayer of this recording whose env is built in control `mode` (built once, closed with this one), or
        None when that mode takes actions of another shape than the recorded ones or its env does not build."""
        if mode not in self._in_modes:
            other = None
            try:
                other = EpisodeReplayer(self.meta, self._options, control_mode=mode)
            except SimreelError:  # its env does not build
                pass
            recorded = tuple(self.meta.action_space.get("shape") or ())
            if other is not None and tuple(other.u.single_action_space.shape) != recorded:
                other.close()
                other = None
            self._in_modes[mode] = other
        return self._in_modes[mode]

    def __enter__(self) -> EpisodeReplayer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ replay
    def replay(self, episode: Episode, *, mode: str = "actions", resync: int | None = None,
               obs: bool = True) -> ReplayedEpisode:
        """Replay `episode` (in memory) in `mode` and return the replayed arrays (compare them with `simreel.verdicts.compare`);
        `obs=False` keeps no observations (an explanation's replays need none)."""
        collected = Collected(obs=obs)
        out = self.replay_rows(EpisodeRows.of(episode), collected, mode=mode, resync=resync)
        out.episode = collected.episode(episode.meta)
        for key in collected.info_unreturned:  # not a value the replay produced: compare_episode names it
            del out.episode.info[key]
        return out

    def replay_rows(self, source: EpisodeRows, sink: BlockSink, *, mode: str = "actions", resync: int | None = None,
                    rows: int | None = None) -> ReplayedEpisode:
        """Replay episode `source` in `mode`, a block of `rows` recorded steps at a time (None: the reader's
        `block_rows`): each recorded block is read, replayed and handed to `sink` with its replay, then dropped, so
        a long episode is never held whole. Returns how it was replayed (`ReplayedEpisode.episode` is None)."""
        if mode not in MODES:
            raise ReplayError(f"unknown replay mode {mode!r}; expected one of {', '.join(MODES)}")
        if resync is not None and (mode != "actions" or resync < 1):
            raise ReplayError(f"resync={resync} needs mode 'actions' and K >= 1")
        start = time.perf_counter()
        run = _Run(source, sink, mode, resync, rows)
        with task_code_errors():
            try:
                out = self._replay(run)
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
                out = self._replay(run)
                out.notes.insert(0, f"replayed with obs_mode={self.obs_mode!r}: the task failed without "
                                    f"observations ({type(exc).__name__}: {exc})")
        out.compare_contacts = self._contacts is not None
        out.seconds = time.perf_counter() - start
        return out

    def _replay(self, run: _Run) -> ReplayedEpisode:
        meta = run.source.meta
        done = self.reset_for(meta)
        self._check_layout()
        scene = self.scene_check(meta)
        run.sink.start()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # ManiSkill warns on every out-of-bounds action; the recording had them too
            out = self._drive(run)
        if scene is None:
            done.notes.append("scene fingerprint not compared: the file holds none (ManiSkill's own files, and "
                              "simreel's from before it kept one)")
        out.scene_differences = scene
        file_notes = list(meta.notes)  # what the reader found in the file about this episode
        out.notes = done.notes + file_notes + done.limits + out.limits + out.notes
        out.limits = file_notes + done.limits + out.limits
        return out

    def _drive(self, run: _Run) -> ReplayedEpisode:
        """Reset the replay as `run.mode` starts, then replay the recorded blocks one by one into `run.sink`."""
        source = run.source
        out = run.out = ReplayedEpisode(None)
        run.info_returned = set()  # a replay again after a rebuild starts afresh
        recorded = source.reset()
        states = run.states = RecordedStates(recorded)
        if run.mode == "states":
            restore_state(self.u, states.row(0), elapsed_steps=0)
        elif run.mode == "actions" and (source.meta.seed is None or source.meta.seed_unchecked):
            limits = self._start_unseeded(source, recorded)
            out.limits += limits
            if limits:
                out.restored_at.append(0)
        run.sink.reset(recorded, self._reset_row(recorded))
        self._stepped = self._stepped or source.length > 0
        step = {"actions": self._step_actions, "states": self._step_states, "step": self._step_restored}[run.mode]
        for first, block in source.blocks(run.rows):
            states.advance(first, block)
            buf = self._block(block)
            actions = self._actions(without_nan(source, first, block["actions"]))
            for i in range(block.rows):
                step(run, buf, i, actions[i])
            run.sink.steps(first, block, buf.block())
            run.info_returned |= buf.info_returned
        self._tell_unreturned_info(run)
        if run.resync:
            out.notes.append(f"restored the recorded state every {run.resync} steps")
        return out

    @staticmethod
    def _tell_unreturned_info(run: _Run) -> None:
        """Tell `run.sink` the recorded info keys the replaying task returned at no step of the episode (it no longer
        returns them): their replayed rows hold the zeros they were filled with, not values to compare. A key returned
        at some steps only is compared, absent rows as zeros: the recorder's rule for absent entries."""
        recorded = [f.name[len("info/"):] for f in run.source.fields if f.name.startswith("info/")]
        unreturned = [key for key in recorded if key not in run.info_returned]
        if unreturned and run.source.length:
            run.sink.info_not_returned(unreturned)


@dataclass
class _Run:
    """One block replay: the recorded episode, where its rows go, the mode and the block size."""

    source: EpisodeRows
    sink: BlockSink
    mode: str
    resync: int | None
    rows: int | None
    out: ReplayedEpisode = field(default_factory=lambda: ReplayedEpisode(None))
    """What the replay found so far (notes, limits, restores)."""
    states: RecordedStates | None = None
    """The recorded states at hand: set as the replay begins."""
    info_returned: set[str] = field(default_factory=set)
    """The recorded info keys the replaying task returned at some step so far."""
