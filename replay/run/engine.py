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
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.errors import EnvBuildError, RecordingFileError, ReplayError, SimreelError, UsageError
from simreel.formats.base import EpisodeRows
from simreel.model.blocks import StepBlock
from simreel.model.episode import Episode
from simreel.model.fields import FLAG_FIELDS
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.model.state_tree import to_numpy
from simreel.options.checks import check_flag, check_mapping, check_text, options_with, text_tuple
from simreel.replay.run.options import MODES
from simreel.sim.fingerprint import SceneDifference
from simreel.sim.rebuild import (
    GYM_MAKE_SEED,
    UNSEEDED_WITHOUT_STATES,
    EpisodeReset,
    build_with_render_fallback,
    env_from_meta,
    import_task_code,
    reset_to_episode,
)
from simreel.sim.state import FastStateReader, check_rebuilt_layout, read_state, restore_state

__all__ = ["MODES", "RESTORING_MODES", "EpisodeReplayer", "ReplayerOptions", "ReplayedEpisode", "ReplayError",
           "GYM_MAKE_SEED", "BlockSink", "Collected", "SceneBefore"]

RESTORING_MODES = ("states", "step")
"""The modes that restore recorded states, so replay no episode's history: they re-run only the last step of the
episode before (`SceneBefore`)."""


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
        control_mode: None: the recorded one (another one to replay converted actions: `simreel.replay.convert.replayer`).
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

    def __post_init__(self) -> None:
        """Check every option's type, so that a wrong one is a `UsageError` here, naming it and what to give, before
        the env is built: not a raw error inside ManiSkill, nor a value taken for another (``need_obs="no"`` as yes,
        ``pose_bodies="cube"`` as four bodies of one letter each). Put them in one form: the bodies as a tuple,
        the env's arguments as a dict."""
        for name in ("need_obs", "need_rewards"):
            check_flag(name, getattr(self, name))
        for name, what in _TEXT_OPTIONS.items():
            check_text(name, getattr(self, name), what, optional=True)
        object.__setattr__(self, "pose_bodies", text_tuple("pose_bodies", self.pose_bodies, "the names of the bodies "
                                                           'whose poses to sample, as a tuple of strings, e.g. ("cube", '
                                                           '"panda/panda_hand")'))
        check_mapping("env_kwargs", self.env_kwargs, 'the gym.make arguments to add as a dict, e.g. '
                      '{"shader_dir": "rt"}')
        object.__setattr__(self, "env_kwargs", dict(self.env_kwargs))


_TEXT_OPTIONS = {
    "obs_mode": 'an observation mode as a string, e.g. "rgb", or None (the recorded one when needed)',
    "render_backend": 'a render backend as a string, e.g. "cpu", or None (the one the observation mode needs)',
    "sim_backend": 'a sim backend as a string, e.g. "physx_cpu", or None (the recorded one)',
    "control_mode": 'a control mode as a string, e.g. "pd_ee_delta_pose", or None (the recorded one)',
}
"""`ReplayerOptions`' options that are strings or None, and what each means."""


@dataclass(frozen=True)
class SceneBefore:
    """The step the recorder's scene simulated last before an episode's reset, whose contacts the observations at
    that reset read: episode `episode`'s step from its state row `step` (`state`, each leaf (1, ...)) with `action`;
    ``SceneBefore()``: none, the scene was just built (no contacts). A restoring replay re-runs it before the reset
    (`EpisodeReplayer.rerun_step_before`)."""

    episode: EpisodeMeta | None = None
    state: dict[str, np.ndarray] = field(default_factory=dict)
    action: np.ndarray | None = None
    step: int = 0


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
            with _older_objects_unscanned():
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
            with _older_objects_unscanned():
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

    # ------------------------------------------------------------------ reset
    def reset_for(self, ep: EpisodeMeta) -> EpisodeReset:
        """Reset the env the way episode `ep` was reset (scene, seed, options: `simreel.sim.rebuild.reset_to_episode`);
        returns what was done, with this replayer's own limits added (body poses, contacts; also those its scene
        met at the reset of `rerun_step_before`, which rebuilt it)."""
        done, _ = self._reset_scene(ep)
        done.limits[:0], self._carried = self._carried, []
        return done

    def _reset_scene(self, ep: EpisodeMeta) -> tuple[EpisodeReset, list[str]]:
        """`reset_for`'s reset, and the limits this replayer met binding to a rebuilt scene (in its limits too)."""
        u = self.u
        bound: list[str] = []
        done = reset_to_episode(self.env, ep, scene_seed=self._scene_seed)
        self._scene_seed = done.scene_seed
        self._scene_builds += done.scene_builds
        self._stepped = self._stepped and not done.scene_builds
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
                bound.append(f"body poses not written: the rebuilt scene has no {', '.join(missing[:3])}")
                self.pose_bodies = []
        if self._contacts is not None:
            try:
                self._contacts.bind(u)
            except KeyError as e:
                bound.append(f"contacts not compared: the rebuilt scene has no body {e}")
                self._contacts = None
        done.limits += bound
        return done, bound

    def forget_scene(self) -> None:
        """Take the env's scene for unknown: the next reset rebuilds it (`reset_to_episode` with ``scene_seed=None``),
        which gives the state of an env fresh from ``gym.make`` again, history included: PhysX's CPU results depend on
        what the scene ran since it was built (`simreel.verdicts.scene_history`)."""
        self._scene_seed = None

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

    def rerun_step_before(self, before: SceneBefore | None) -> None:
        """Re-run the step the recorder's scene simulated last before an episode's reset (`SceneBefore`; None:
        nothing to re-run), just before a restoring replay of that episode: its reset then keeps that step's
        contacts (a reset simulates nothing). For a scene then just built, the scene is rebuilt at the next reset if
        it has stepped since."""
        if before is None:
            return
        if before.episode is None:
            if self._stepped:
                self.forget_scene()
            return
        with task_code_errors():
            self._carried += self._reset_scene(before.episode)[1]
            self._check_layout()
            restore_state(self.u, before.state, elapsed_steps=before.step)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # an out-of-bounds action: the recording had it too
                self.u._step_action(self._actions(before.action))
        self._stepped = True

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

    def _start_unseeded(self, source: EpisodeRows, recorded: StepBlock) -> list[str]:
        """Start an episode without a seed where it began (`recorded`: its reset row). Where the recording holds the
        random generators its reset drew from (`EpisodeMeta.reset_generators`), the replay's reset drew from them
        too (`reset_for`): a reset that remade the recorded initial state bit for bit is kept, with everything PhysX
        and the controllers keep beside the state. Otherwise the recorded initial state is restored: the limit that
        says so, and why (none for a seeded episode, or a remade reset). `RecordingFileError` where the recording
        holds no states to start from: where the episode began is then unknown, and stepping from another start would
        judge another trajectory."""
        if source.meta.seed is not None and not source.meta.seed_unchecked:
            return []
        row = _States(recorded).row(0)
        if not row:
            raise RecordingFileError(getattr(source, "path", None) or "the recording",
                                     f"episode {source.meta.index}: {UNSEEDED_WITHOUT_STATES}: it cannot be replayed")
        if source.meta.seed_unchecked:
            return self._check_seed(source.meta.seed, row)
        if source.meta.reset_generators:
            differing = _differing_leaves(row, self._state())
            if not differing:
                return []
        restore_state(self.u, row, elapsed_steps=0)
        restored = ["actions replayed from the recorded initial state"]
        if not source.meta.reset_generators:
            return restored
        return [f"the reset from the recorded generator states did not remake the recorded initial state "
                f"({', '.join(differing[:3])} differ: the reset drew from something else too, or another engine "
                "replays it)", *restored]

    def _check_seed(self, seed: int | None, row: dict[str, np.ndarray]) -> list[str]:
        """Start an episode whose `seed` may be stale (``EpisodeMeta.seed_unchecked``), reset with it, where it began:
        a reset that remade the recorded initial state (`row`) bit for bit is kept; else that state is restored, and
        the limits say so, naming the stale seed."""
        differing = _differing_leaves(row, self._state())
        if not differing:
            return []
        restore_state(self.u, row, elapsed_steps=0)
        return [f"stale seed: a reset with episode_seed {seed} did not remake the recorded initial state "
                f"({', '.join(differing[:3])} differ: the episode was reset without a seed)",
                "actions replayed from the recorded initial state"]

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
        states = run.states = _States(recorded)
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

    def _step_actions(self, run: _Run, buf: _Block, i: int, action: Any) -> None:
        t = run.states.first + i
        if run.resync and t and t % run.resync == 0:
            restore_state(self.u, run.states.row(t), elapsed_steps=t)
            run.out.restored_at.append(t)
        self._after_step(buf, i, self._step(action))

    def _step_restored(self, run: _Run, buf: _Block, i: int, action: Any) -> None:
        t = run.states.first + i
        if t or run.source.meta.initial_state_known:  # else step 0 starts from the reproduced reset
            restore_state(self.u, run.states.row(t), elapsed_steps=t)
        self._after_step(buf, i, self._step(action))

    def _step_states(self, run: _Run, buf: _Block, i: int, action: Any) -> None:
        u, states, t = self.u, run.states, run.states.first + i
        restore_state(u, states.row(t), elapsed_steps=t)
        # one step from the recorded state t, for its contacts and the controller's target; without the
        # observation `step` would compute (with cameras: a frame rendered for nothing, half the time)
        u._step_action(action)
        contacts = self._contacts.sample()[0] if buf.contact_forces is not None else None
        restore_state(u, states.row(t + 1), elapsed_steps=t + 1)
        info = u.get_info()
        obs = u.get_obs(info, unflattened=True) if self.obs_mode != "none" else {}
        reward = u.get_reward(obs=obs, action=action[None], info=info)
        terminated = _flag(info, "success") or _flag(info, "fail")
        truncated = self.max_episode_steps is not None and t + 1 >= self.max_episode_steps
        self._after_step(buf, i, (None, reward, terminated, truncated, info))
        if contacts is not None:
            buf.contact_forces[i] = contacts
        if self.need_obs:
            buf.set_obs(i, self._obs(u._flatten_raw_obs(obs) if obs else u.get_obs(info)))

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

    def _block(self, recorded: StepBlock, actions: np.ndarray | None = None) -> _Block:
        """Buffers for the replay of the recorded block (`actions`: what is stepped, if not the recorded actions)."""
        return _Block(recorded, actions, n_channels=len(self.meta.contact_channels) if self._contacts else 0,
                      n_poses=len(self.pose_bodies))

    def _after_step(self, buf: _Block, i: int, outcome: tuple[Any, Any, Any, Any, Any]) -> None:
        """Store the outcome ``(obs, reward, terminated, truncated, info)`` of the block's step i and the state after it."""
        obs, reward, terminated, truncated, info = outcome
        buf.rewards[i] = _scalar(reward)
        buf.terminated[i] = _scalar(terminated)
        buf.truncated[i] = _scalar(truncated)
        buf.success[i] = _flag(info, "success")
        buf.fail[i] = _flag(info, "fail")
        for key, dst in buf.info.items():
            value = info.get(key)
            if value is not None:
                dst[i] = _scalar(value)
                buf.info_returned.add(key)
        if buf.contact_forces is not None:
            buf.contact_forces[i] = self._contacts.sample()[0]
        self._after_state(buf, i, obs)

    def _after_state(self, buf: _Block, i: int, obs: Any) -> None:
        """Store the state the env holds now (and its observation and body poses) as the block's per-state row i."""
        buf.set_state(i, self._state())
        if self.need_obs and obs is not None:
            buf.set_obs(i, self._obs(obs))
        if buf.body_poses is not None:
            buf.body_poses[i] = self._poses()

    def _poses(self) -> np.ndarray:
        from simreel.sim.poses import sample_body_poses

        return sample_body_poses(self.u, self.pose_bodies)[0]

    def _reset_row(self, recorded: StepBlock) -> StepBlock:
        """The replay's row 0 (state, observations, body poses right after its reset), laid out like `recorded`."""
        buf = self._block(recorded)
        self._after_state(buf, 0, self.u.get_obs() if self.need_obs else None)
        return buf.block()

    def _actions(self, actions: np.ndarray) -> Any:
        import torch

        return torch.from_numpy(np.ascontiguousarray(actions)).to(self.u.device)

    def _step(self, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        """`unwrapped.step` plus the time limit (what ManiSkill's TimeLimitWrapper adds), without the wrapper stack."""
        obs, reward, terminated, _, info = self.u.step(action)
        limit = self.max_episode_steps
        truncated = limit is not None and self.u._elapsed_steps[0].item() >= limit
        return obs, reward, terminated, truncated, info


@contextlib.contextmanager
def _older_objects_unscanned() -> Iterator[None]:
    """ManiSkill collects garbage (``gc.collect()``) as it builds and as it clears a scene: 0.2 s each in a process
    holding torch and a replay's objects, two thirds of the time to verify one short episode. In the block the objects
    alive before it are out of the collector's sight (``gc.freeze``), and back in it after: garbage among them is
    collected later, as any is."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@contextlib.contextmanager
def task_code_errors() -> Iterator[None]:
    """Raise what the user's task code raised in the block as `TaskCodeError` (`task_code_error`): that episode's
    verdict is then an error naming the task's line, and a dataset run goes on with the next episode."""
    from simreel.sim.user_code import task_code_error

    try:
        yield
    except SimreelError:
        raise
    except Exception as exc:
        error = task_code_error(exc)
        if error is None:
            raise
        raise error from exc


def _differing_leaves(recorded: dict[str, np.ndarray], live: dict[str, np.ndarray]) -> list[str]:
    """The leaves of state row `recorded` that the `live` state does not hold bit for bit (in the recorded dtype)."""
    return [path for path, a in recorded.items()
            if path not in live or not np.array_equal(np.asarray(live[path], a.dtype).reshape(a.shape), a)]


def without_nan(source: EpisodeRows, first: int, actions: np.ndarray) -> np.ndarray:
    """`actions`, the recorded actions of `source` from step `first`; `RecordingFileError` naming the episode and the
    first step whose action holds NaN: ManiSkill's CPU sim refuses to step one (a GPU-sim recording may hold NaN it
    stepped, which no replay here can repeat)."""
    nan = np.isnan(actions).reshape(len(actions), -1).any(axis=1)
    if nan.any():
        where = getattr(source, "path", None) or "the recording"
        raise RecordingFileError(where, f"episode {source.meta.index}: the recorded action of step "
                                        f"{first + int(np.argmax(nan))} holds NaN, which ManiSkill's CPU sim refuses "
                                        "to step (on it, no recorder stepped it: the file was altered or damaged)")
    return actions


class _States:
    """The recorded states a block replay restores: state row t of the episode, whether it is the last row of the
    block before (or the reset row) or a row of the current block."""

    def __init__(self, reset: StepBlock) -> None:
        self.names = [name for name in reset.arrays if name.startswith("env_states/")]
        self.first = 0
        self._before = {name[len("env_states/"):]: reset[name] for name in self.names}
        self._block: dict[str, np.ndarray] = {}

    def advance(self, first: int, block: StepBlock) -> None:
        """Move to the block of steps `first`.. (its per-state rows: the states after them)."""
        if self._block:
            self._before = {p: a[-1:] for p, a in self._block.items()}
        self.first = first
        self._block = {name[len("env_states/"):]: block[name] for name in self.names}

    def row(self, t: int) -> dict[str, np.ndarray]:
        """State row t (0: after the reset; t: after step t - 1), each leaf (1, ...)."""
        i = t - self.first
        if i == 0:
            return self._before
        return {p: a[i - 1 : i] for p, a in self._block.items()}


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
    states: _States | None = None
    """The recorded states at hand: set as the replay begins."""
    info_returned: set[str] = field(default_factory=set)
    """The recorded info keys the replaying task returned at some step so far."""


class _Block:
    """Preallocated arrays of the replay of one recorded block (or of the reset row), laid out like it: per-step
    rows, and per-state rows holding the states after those steps (for the reset row: the state after the reset)."""

    def __init__(self, recorded: StepBlock, actions: np.ndarray | None, *, n_channels: int, n_poses: int = 0) -> None:
        k = recorded.rows
        self.per_step = "actions" in recorded.arrays
        self.actions = recorded.get("actions") if actions is None else actions
        self.rewards = np.zeros(k, np.float32)
        for name in FLAG_FIELDS:
            setattr(self, name, np.zeros(k, bool))
        self.env_states = {n[len("env_states/"):]: np.zeros_like(a) for n, a in recorded.arrays.items()
                           if n.startswith("env_states/")}
        self.info = {n[len("info/"):]: np.zeros_like(a) for n, a in recorded.arrays.items() if n.startswith("info/")}
        self.info_returned: set[str] = set()
        """The keys of `info` the task returned at some step of the block (the others hold only their zeros)."""
        self.contact_forces = np.zeros((k, n_channels, 3), np.float32) if n_channels and self.per_step else None
        self.obs: dict[str, np.ndarray] = {}
        self.body_poses = np.zeros((k, n_poses, 7), np.float32) if n_poses else None
        self.rows = k

    def set_state(self, row: int, flat: dict[str, np.ndarray]) -> None:
        for p, dst in self.env_states.items():
            src = flat.get(p)
            if src is not None:
                dst[row] = src[0]

    def set_obs(self, row: int, flat: dict[str, np.ndarray]) -> None:
        for p, a in flat.items():
            dst = self.obs.get(p)
            if dst is None:
                dst = self.obs[p] = np.zeros((self.rows, *a.shape), a.dtype)
            dst[row] = a

    def block(self) -> StepBlock:
        """The replayed rows as flat fields (the reset row: per-state fields only)."""
        arrays: dict[str, np.ndarray] = {}
        if self.per_step:
            arrays.update({"actions": self.actions, "rewards": self.rewards,
                           **{name: getattr(self, name) for name in FLAG_FIELDS}})
            arrays.update({f"info/{k}": a for k, a in self.info.items()})
            if self.contact_forces is not None:
                arrays["contact_forces"] = self.contact_forces
        arrays.update({f"env_states/{p}": a for p, a in self.env_states.items()})
        arrays.update({f"obs/{p}": a for p, a in self.obs.items()})
        if self.body_poses is not None:
            arrays["body_poses"] = self.body_poses
        return StepBlock(arrays, self.rows)


class BlockSink:
    """Where a block replay (`EpisodeReplayer.replay_rows`) hands each recorded block with its replay. Subclasses
    must not keep a block's arrays beyond the call unless they mean to hold the episode (`Collected`)."""

    def start(self) -> None:
        """A replay of the episode begins (again, if the engine had to rebuild its env: drop what came before)."""

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        """Row 0 of the per-state fields, recorded and replayed."""

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        """The block of steps `first`.. , recorded and replayed."""

    def info_not_returned(self, keys: list[str]) -> None:
        """After the last block: the recorded info `keys` the replaying task returned at no step (their replayed rows
        hold zeros, as the recorder writes an absent entry, not values it produced)."""


class Collected(BlockSink):
    """Keeps every replayed block, to put the replayed episode together (`episode`); `obs=False` drops the
    observations."""

    def __init__(self, *, obs: bool = True) -> None:
        self.obs = obs
        self.start()

    def start(self) -> None:
        self._reset: StepBlock | None = None
        self._blocks: list[StepBlock] = []
        self.info_unreturned: list[str] = []
        """The recorded info keys the replay never returned (`BlockSink.info_not_returned`)."""

    def _kept(self, block: StepBlock) -> StepBlock:
        return block if self.obs else StepBlock({k: a for k, a in block.arrays.items() if not k.startswith("obs/")},
                                                block.rows)

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self._reset = self._kept(replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self._blocks.append(self._kept(replayed))

    def info_not_returned(self, keys: list[str]) -> None:
        self.info_unreturned = list(keys)

    def episode(self, meta: EpisodeMeta) -> Episode:
        """The replayed episode (a copy of `meta`; per-step fields empty when it has no step)."""
        assert self._reset is not None
        per_state = set(self._reset.arrays)
        template = self._blocks[0].arrays if self._blocks else {"actions": np.zeros((0, 0), np.float32)}
        names = dict.fromkeys([*template, *per_state])
        arrays = {n: np.concatenate(([self._reset[n]] if n in per_state else [])
                                    + [b[n] for b in self._blocks]) for n in names}
        if not self._blocks:
            arrays.update({n: np.zeros(0, bool) for n in FLAG_FIELDS}, rewards=np.zeros(0, np.float32))
        return Episode.from_fields(dataclasses.replace(meta), arrays)
