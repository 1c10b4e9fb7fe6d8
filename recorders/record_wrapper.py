"""`RecordWrapper`: records a ManiSkill env's episodes, with full state dicts and contacts, to a file.

Every parallel env's episode is its own episode on disk. An episode runs from a reset of its env to
the next reset of that env (a partial reset `options={"env_idx": [...]}` ends only those envs'
episodes) or to `close()`. Steps are buffered in blocks of `block_steps` and streamed to the writer,
so memory does not grow with episode length. The writer runs in a child process (`simreel.recorders.writer_process`)
and commits the episodes a reset ends while the env resets; `reset()` returns once they are durable. After
each step the recorder copies out what it needs and converts a block of steps at once (`StepBuffer`):
right after a physics step every numpy call costs several times its usual price.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import numbers
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from simreel.errors import EpisodeLayoutError, SimreelError, StateLayoutError, Terminated, UsageError
from simreel.formats import check_writer_options, open_writer, records_poses_by_default, writes_scene
from simreel.io.durable import deferred_signals
from simreel.model.blocks import StepBlock
from simreel.model.fields import episode_fields
from simreel.model.lineage import SceneChain
from simreel.model.meta import EpisodeMeta, json_default
from simreel.model.state_tree import LeafSpec, layout_differences, layout_of, to_numpy
from simreel.options.checks import check_flag, check_text, options_with, path_text, whole_number
from simreel.recorders.scene_drawing import SceneDrawing
from simreel.recorders.step_buffer import StepBuffer
from simreel.recorders.step_scalars import StepScalars, scalar_info
from simreel.recorders.wrapper_policy import refuse_reshaping_wrappers
from simreel.recorders.writer_process import ProcessWriter
from simreel.sim.actions import ActionCheck
from simreel.sim.contacts import ContactSampler, contact_channels, contacts_spec
from simreel.sim.describe import flatten_obs, recording_meta
from simreel.sim.fingerprint import fingerprint_changes, scene_fingerprint
from simreel.sim.generators import capture_generators, consumed_generators
from simreel.sim.poses import pose_body_names, sample_body_poses
from simreel.sim.seeds import SEED_LIMIT, is_seed
from simreel.sim.state import FastStateReader, check_same_layout, read_state
from simreel.sim.step_rows import ActionRows, PackedRows
from simreel.sim.user_code import found_spec, import_specs

__all__ = ["RecordWrapper", "RecordOptions", "what_stopped"]


@dataclass(frozen=True)
class RecordOptions:
    """What `RecordWrapper` records and how.

    Attributes:
        contacts: "auto" (net force on every moving body + the task's or the robot fingers' pairs), "none",
            or explicit pairs "panda/panda_leftfinger:cube,..." (or a list of "A:B" strings).
        record_obs: also record observations (T+1 rows per episode).
        poses: also record world poses of every body (needed by MCAP's transform channel; costs about as much
            per step as the state dict). None: the format's default (on for .mcap, off for .h5).
        overwrite: replace an existing file instead of refusing.
        block_steps: steps buffered in memory before they are streamed to the file.
        imports: `--import` specs that registered the task (a .py file or a module name; one string is one spec),
            stored so replay can import them again (a file by its absolute path: `simreel.sim.user_code.found_spec`);
            each must be found when the recorder starts.
        command: the command line, stored for provenance.
        writer_options: keyword options for the format's writer (HDF5: `compression`; MCAP: `McapOptions`); another
            name is refused when the recorder starts, naming those the format takes.
        writer_process: write the file from a child process (`simreel.recorders.writer_process`), so an episode's
            commit runs beside the env's reset; `reset()` still returns only once the episodes it ended are
            committed. False: write in this process (one process less; each commit then adds to the reset).
    """

    contacts: str | None = "auto"
    record_obs: bool = False
    poses: bool | None = None
    overwrite: bool = False
    block_steps: int = 256
    imports: tuple[str, ...] = ()
    command: str = ""
    writer_options: Mapping[str, Any] = field(default_factory=dict)
    writer_process: bool = True

    def __post_init__(self) -> None:
        """Check the options whose wrong type would fail later as a raw Python error, or be taken for another value (a
        flag given as a string), or be stored where the file could not be read back (a command that is not a
        string); put them in one form: contacts as one string (`contacts_spec`), imports as a tuple."""
        object.__setattr__(self, "block_steps", whole_number(
            "block_steps", self.block_steps, "the number of steps to buffer, an int ≥ 1 (default 256)", minimum=1))
        for name in ("record_obs", "overwrite", "writer_process") + (("poses",) if self.poses is not None else ()):
            check_flag(name, getattr(self, name))
        check_text("command", self.command, "the command line as a string (stored for provenance)")
        object.__setattr__(self, "contacts", contacts_spec(self.contacts))
        object.__setattr__(self, "imports", import_specs(self.imports))
        if not isinstance(self.writer_options, Mapping) or not all(isinstance(k, str) for k in self.writer_options):
            raise UsageError(f"writer_options={self.writer_options!r}: give a dict of the format's writer options, "
                             "e.g. {\"compression\": \"gzip\"}")


class RecordWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Records every episode of `env` to `path` (.h5 or .mcap).

    Args:
        env: a `gym.make`'d ManiSkill 3 env (any num_envs, CPU or GPU sim), possibly wrapped.
        path: output file; the suffix picks the format.
        options: a `RecordOptions`; keyword arguments override its fields, e.g.
            ``RecordWrapper(env, "pick.h5", contacts="none", record_obs=True)``.

    Like gymnasium's own wrappers it remembers its constructor arguments, so ``env.spec`` lists it.
    """

    def __init__(self, env: gym.Env, path: str | Path, options: RecordOptions | None = None, **overrides: Any) -> None:
        path = path_text("path", path, "the file to record to, a str or pathlib.Path ending in .h5 or .mcap")
        opts = options_with(RecordOptions, options, overrides, 'RecordWrapper(env, path, contacts="none")')
        gym.utils.RecordConstructorArgs.__init__(self, path=str(path), **_constructor_options(opts))
        gym.Wrapper.__init__(self, env)
        refuse_reshaping_wrappers(env, opts.record_obs)
        check_writer_options(path, opts.writer_options)
        self.options = opts
        starting = ProcessWriter(path) if opts.writer_process else None  # its imports run while the env is described
        try:
            self._setup(env, path, starting)
        except BaseException:
            if hasattr(self, "_writer"):  # opened, then setting up failed: drop the new recording
                with contextlib.suppress(Exception):  # the error that stopped the setup is the one to raise
                    self._writer.abort()
            elif starting is not None:
                starting.cancel()
            raise

    def _setup(self, env: gym.Env, path: str | Path, starting: ProcessWriter | None) -> None:
        opts = self.options
        u = env.unwrapped
        self._u = u
        self._n = int(u.num_envs)
        self._sampler = ContactSampler(contact_channels(u, opts.contacts))
        self._bind_sampler()
        self._fast: FastStateReader | None = None
        self._state_rows: PackedRows | None = None
        """The row source of the fast reader's captures, its leaves named as the recording's fields."""
        self._fast_unchecked = False
        self._fast_refuted = False
        self._fast_scene: Any = None
        """The PhysX scene whose fast reader passed the check after a step (None: none yet, or rebuilt)."""
        self.meta = self._describe(env, path)  # refuses an action space other than a Box
        self._rows_beside_state = opts.record_obs or bool(self.meta.pose_bodies)
        """Whether each step records rows besides the state (`_per_state_rows`): observations or body poses."""
        self._actions = ActionCheck(self.meta.env_id, tuple(u.single_action_space.shape), self._n)
        """What every action passes before the env steps with it (its numbers, copied out, are what is recorded)."""
        if starting is not None:
            self._writer = starting.open(self.meta, overwrite=opts.overwrite, **opts.writer_options)
        else:
            self._writer = open_writer(path, self.meta, overwrite=opts.overwrite, **opts.writer_options)
        self._buffer = StepBuffer(opts.block_steps, self._n)
        self._sinks: list[Any] = [None] * self._n
        self._episodes: list[EpisodeMeta | None] = [None] * self._n
        self._open = 0
        self._refused: dict[int, str] = {}
        """Envs whose running episode stopped where the sink refused its steps (`_refuse`), with what it refused."""
        # Per-env running counts, folded into each episode's EpisodeMeta when it ends: its length is the rows handed
        # to its sink (so it always says what the file holds); its success flags are updated from each of those blocks.
        self._sent = [0] * self._n
        self._last_scalars: list[Any] | None = None
        """The last step's captured scalars (`StepScalars.capture`): whether it ended each env's episode."""
        self._success = np.zeros(self._n, bool)
        self._ever_success = np.zeros(self._n, bool)
        self._has_success = "success" in self.meta.info_layout
        self._scalars = StepScalars(self._n, [(f"info/{k}", np.dtype(s.dtype)) for k, s in self.meta.info_layout.items()])
        self._action_rows = ActionRows(self._n)
        self._defer = self._writer.converts_captures
        """Whether blocks go to the writer process with their captures unconverted (`StepBuffer.take`): it converts
        them while the env steps on."""
        self._next_index = 0
        self._scene_seed: list[int | None] = [None] * self._n
        self._scene_changes: list[dict[str, Any]] = [{} for _ in range(self._n)]
        self._chain_start = [0] * self._n
        self._chain_ran = [0] * self._n
        """Per sub-scene: the index of its chain's first episode, and the episodes committed in that chain (each
        episode's `EpisodeMeta.chain`; the env is taken as fresh from ``gym.make``, as `simreel.verdicts.scene_history` says)."""
        self._fingerprint_scenes(range(1, self._n))  # sub-scene 0's is the recording's own
        self._drawing = SceneDrawing(self._writer, u, enabled=writes_scene(path))
        self._drawing.send(range(self._n))
        self._closed = False

    def _describe(self, env: gym.Env, path: str | Path) -> Any:
        u, opts = self._u, self.options
        obs_layout = layout_of(flatten_obs(u.get_obs(), u.obs_mode), batched=True) if opts.record_obs else {}
        poses = records_poses_by_default(path) if opts.poses is None else opts.poses
        return recording_meta(
            env,
            contact_channels=self._sampler.channels,
            info_layout=layout_of(scalar_info(u.get_info(), self._n), batched=True),
            obs_layout=obs_layout,
            pose_bodies=pose_body_names(u) if poses else [],
            imports=[found_spec(spec) for spec in opts.imports],  # a file by its absolute path
            command=opts.command,
        )

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None) -> Any:
        self._check_open("reset()")
        options = _reset_options(options)
        idxs = self._envs_to_reset(options.get("env_idx"))
        self._check_seeds(seed, idxs)
        for i in idxs:
            self._finish(i)
        if self._buffer.rows and all(s is None for s in self._sinks):
            self._buffer.rewind()
        self._writer.checkpoint()  # a writer process commits the episodes just ended while the env resets
        before = capture_generators(self._u) if self._captures_generators(seed) else None
        obs, info = self.env.reset(seed=seed, options=options or None)
        generators = consumed_generators(before, self._u) if before is not None else {}
        reconfigured = bool(to_numpy(info.get("reconfigure", False)).any()) if "reconfigure" in info else False
        state = read_state(self._u)
        packed = self._bind_fast_reader(state, reconfigured)
        unpacked = self._check_state_layout(state, packed)
        if reconfigured or self._sampler.px is not self._u.scene.px:
            self._bind_sampler()
        reset_rows, captured = self._reset_rows(state, unpacked, obs, packed)
        stored_options = json.loads(json.dumps({k: v for k, v in options.items() if k != "env_idx"},
                                               default=json_default))
        if reconfigured:
            self._fingerprint_scenes(range(self._n))
            self._drawing.send(range(self._n))
        for i, seed_i in zip(idxs, self._episode_seeds(seed, idxs), strict=True):
            if reconfigured:
                self._scene_seed[i] = seed_i
            meta = EpisodeMeta(index=self._next_index, seed=seed_i, reset_options=stored_options, env_idx=i,
                               reconfigured=reconfigured, scene_seed=self._scene_seed[i],
                               scene_changes=self._scene_changes[i], chain=self._chain_of(i, reconfigured),
                               reset_generators=dict(generators))
            self._start(i, meta, StepBlock({k: a[i : i + 1] for k, a in reset_rows.items()}, 1, captured))
        self._settle()
        return obs, info

    def _chain_of(self, i: int, reconfigured: bool) -> SceneChain:
        """`EpisodeMeta.chain` of the episode sub-scene i begins (its reset `reconfigured` the scene or not): a chain
        starts at the first committed episode since the scene was built (an episode of no step, discarded, ran
        nothing)."""
        if reconfigured:
            self._chain_ran[i] = 0
        if not self._chain_ran[i]:
            self._chain_start[i] = self._next_index
        return SceneChain(self._chain_start[i], self._chain_ran[i])

    def _envs_to_reset(self, env_idx: Any) -> list[int]:
        """The envs a reset with ``options={"env_idx": env_idx}`` resets (None: all of them); `UsageError`, before
        anything changes, for what ManiSkill would fail on inside its reset (a single index, which it takes the
        ``len()`` of; an index out of range) or would reset wrongly (an env named twice)."""
        if env_idx is None:
            return list(range(self._n))
        named = to_numpy(env_idx)
        if named.ndim == 0:
            example = [int(env_idx)] if isinstance(env_idx, numbers.Integral) else [0]
            raise UsageError(f"reset(options={{'env_idx': {env_idx!r}}}): give a list of the envs to reset, from 0 to "
                             f"{self._n - 1}, e.g. {{'env_idx': {example}}} (ManiSkill takes no single index)")
        named = named.reshape(-1)
        if named.size and named.dtype.kind not in "iu":
            raise UsageError(f"reset(options={{'env_idx': ...}}) holds {named.dtype} values; give the indices of the "
                             f"envs to reset, from 0 to {self._n - 1}")
        idxs = [int(i) for i in named]
        if not idxs or len(set(idxs)) != len(idxs) or not all(0 <= i < self._n for i in idxs):
            raise UsageError(f"reset(options={{'env_idx': {idxs}}}): name each env to reset once, from 0 to "
                             f"{self._n - 1} (an env named twice would begin two episodes at once)")
        return idxs

    def _check_seeds(self, seed: Any, idxs: list[int]) -> None:
        """Refuse, before anything changes, a seed ManiSkill would fail on inside its reset, once the episodes this
        reset ends were committed (anything but ints from 0 to 2**32 - 1: `is_seed`), and a seed list of another
        length than one seed, one per env, or one per env reset (`idxs`): ManiSkill 3.0.1 takes any list as the
        episode seeds of all its envs, so with another length no seed belongs to an env and the recording would lose
        its seed (`_episode_seeds`)."""
        if seed is None:
            return
        seeds = _seed_list(seed)
        if seeds is None and not is_seed(seed):
            raise UsageError(f"reset(seed={seed!r}): ManiSkill takes seeds from 0 to {SEED_LIMIT - 1}; give one such "
                             f"int, or a list of one per env ({self._n})")
        bad = [s for s in seeds or () if not is_seed(s)]
        if bad:
            raise UsageError(f"reset(seed=...) holds {bad[0]!r}: ManiSkill takes seeds from 0 to {SEED_LIMIT - 1}; "
                             f"give ints in that range, one seed or a list of one per env ({self._n})")
        count = 1 if seeds is None else len(seeds)
        if count not in (1, self._n, len(idxs)):
            per_reset = f" or one per env reset ({len(idxs)})" if len(idxs) != self._n else ""
            raise UsageError(f"reset(seed=...) got {count} seeds for {self._n} env(s); give one seed, or a list of one "
                             f"seed per env ({self._n}){per_reset}")

    def _settle(self) -> None:
        """Wait until the writer has committed the episodes this reset ended (a writer process commits them while the
        env resets); raises what the writer met, e.g. a full disk."""
        self._writer.settle()

    @property
    def episodes_committed(self) -> list[EpisodeMeta]:
        """The episodes committed (durable) so far, in the order they were committed; a writer process reports them
        when the recorder settles (at the end of each reset) and at `close`."""
        return self._writer.committed

    def _start(self, i: int, meta: EpisodeMeta, reset: StepBlock) -> None:
        """Begin env i's episode `meta`. Signals are held until it is noted here: a Ctrl-C raised as the writer
        returns its sink would leave the writer an episode this recorder cannot end (never discarded or committed)."""
        with deferred_signals():
            self._sinks[i] = self._writer.begin_episode(meta, reset)  # first: it raises what the writer met
            self._next_index += 1
            self._episodes[i] = meta
            self._open += 1
            self._sent[i] = 0
            self._success[i] = self._ever_success[i] = False
            self._buffer.start[i] = self._buffer.rows

    def step(self, action: Any) -> Any:
        if self._open < self._n or self._refused:
            self._check_open("step()")
            self._check_not_refused()
            raise UsageError("RecordWrapper.step() before reset(): reset the env first so the episode has a start")
        actions = self._actions(action)
        result = self.env.step(action)
        fields, captures = self._after_step(result[0])
        if isinstance(actions, list):
            captures.append((self._action_rows, actions))
        else:
            fields["actions"] = actions
        self._last_scalars = self._scalars.capture(*result[1:])
        captures.append((self._scalars.rows, self._last_scalars))
        buffer = self._buffer
        try:
            buffer.push(fields, captures)
        except (ValueError, TypeError) as e:  # a row that no longer fits its field: diagnosed only then
            self._refuse_step(fields, e)
        if buffer.full:
            with deferred_signals():  # `_flush`
                self._flush_all()
        return result

    def _flush_all(self) -> None:
        """Hand every env's buffered steps to its episode's sink and start the buffer over. Steps a sink refuses (a
        block that breaks the layout) are lost and stop their episode there (`_refuse`); the first refusal is raised
        once the other envs' steps are handed over."""
        refusal = None
        for i in range(self._n):
            try:
                self._flush(i)
            except EpisodeLayoutError as e:
                self._refuse(i, f"the writer refused the steps from there on ({e})")
                refusal = refusal or e
        self._buffer.rewind()
        if refusal is not None:  # the buffer's fields may be shaped after a refused row: it makes them again
            self._buffer = StepBuffer(self.options.block_steps, self._n)
            raise refusal

    def _refuse(self, i: int, why: str) -> None:
        """Stop env i's episode where its steps could not be recorded (`why`: its sink refused them, or a step's rows
        did not fit, `_refuse_step`): a later step would leave a hole in it. It is committed with the steps handed
        over before, and a note, when the env is reset (or the recording stopped or closed); until then `step()`
        refuses to run (`_check_not_refused`)."""
        self._refused[i] = why
        self._episodes[i].notes.append(f"cut short at step {self._sent[i]}: {why}")

    def _check_not_refused(self) -> None:
        """`UsageError` where an env's episode stopped at steps that could not be recorded (`_refuse`), saying how to
        go on."""
        if not self._refused:
            return
        i, why = next(iter(self._refused.items()))
        reset = "reset()" if self._n == 1 else f"reset(options={{'env_idx': [{i}]}})"
        raise UsageError(f"RecordWrapper.step(): episode {self._episodes[i].index} (env {i}) stopped at step "
                         f"{self._sent[i]}: {why}; {reset} to begin the next episode")

    def _refuse_step(self, fields: dict[str, np.ndarray], error: Exception) -> None:
        """A step whose rows did not fit the buffer (`error`, what storing them raised): where a field changed shape or
        kind of dtype since the recording began, or is missing or new (`FieldsChanged`), hand every env's steps before
        it to its sink, stop every running episode there (`_refuse`; one push holds all envs' rows) and raise
        `EpisodeLayoutError` naming the fields; otherwise `error` is the recorder's own bug and goes on as it is."""
        changes = self._layout_changes(fields, error)
        if not changes:
            raise error
        why = f"its rows did not fit the recording's layout ({'; '.join(changes)})"
        with deferred_signals():
            try:
                self._flush_all()  # the steps before this one, each env's, are handed over
            finally:
                for i in range(self._n):
                    if self._sinks[i] is not None and i not in self._refused:
                        self._refuse(i, why)
        stopped = (f"episode {self._episodes[0].index} stops at step {self._sent[0]}, kept with the steps before it; "
                   "reset() to begin the next" if self._n == 1 else "every running episode stops at this step, kept "
                   "with the steps before it; reset() to begin the next ones")
        raise EpisodeLayoutError(f"{self.meta.env_id}: a step's rows do not fit the recording's layout "
                                 f"({'; '.join(changes)}), which every step keeps; {stopped}") from None

    def _layout_changes(self, fields: dict[str, np.ndarray], error: Exception) -> list[str]:
        """One line per field of a step (all envs' rows) missing from it, new in it (`FieldsChanged`, the buffer's
        `error`), or whose per-env shape or kind of dtype is not the recording's: ``"obs: recorded (42,) float32, now
        (43,) float32"``. Run only once storing a step has failed."""
        recorded = {f.name: LeafSpec(f.shape, f.dtype) for f in episode_fields(self.meta)}
        now = layout_of({name: to_numpy(a) for name, a in fields.items()}, batched=True)
        changed = [name for name, spec in now.items() if name in recorded and (spec.shape != recorded[name].shape
                   or np.dtype(spec.dtype).kind != np.dtype(recorded[name].dtype).kind)]
        missing, new = getattr(error, "missing", []), getattr(error, "new", [])
        return layout_differences({name: recorded[name] for name in [*changed, *missing] if name in recorded},
                                  {name: now[name] for name in [*changed, *new] if name in now})

    def _after_step(self, obs: Any) -> tuple[dict[str, np.ndarray], list[tuple[Any, Any]]]:
        """The state, observations, poses and contact forces after a step: (fields read now, what is captured now
        and converted with its block: `StepBuffer` row sources and their captures)."""
        captures: list[tuple[Any, Any]] = []
        state, packed = self._state()
        if packed is not None:
            captures.append((self._state_rows, packed))
        fields = self._per_state_rows(state, obs) if state or self._rows_beside_state else {}
        if self._contacts_captured:
            captures.append((self._sampler.row_source, self._sampler.capture()))
        elif self._sampler.channels:
            fields["contact_forces"] = self._sampler.sample()
        return fields, captures

    def _per_state_rows(self, state: dict[str, np.ndarray], obs: Any) -> dict[str, np.ndarray]:
        """The per-state fields now, for every env: state, observations (when recorded) and body poses."""
        fields = {f"env_states/{p}": a for p, a in state.items()}
        if self.options.record_obs:
            fields.update({f"obs/{p}": a for p, a in flatten_obs(obs, self._u.obs_mode).items()})
        if self.meta.pose_bodies:
            fields["body_poses"] = sample_body_poses(self._u, self.meta.pose_bodies)
        return fields

    def discard_running(self) -> None:
        """Drop the episodes still running (their steps so far are not written); committed ones stay."""
        for i, sink in enumerate(self._sinks):
            if sink is not None:
                sink.discard()
                self._sinks[i] = None
                self._episodes[i] = None
                self._open -= 1
        self._refused.clear()
        self._buffer.rewind()

    def close(self) -> None:
        """Commit the running episodes that have at least one step, close the file and the env (the env also when
        the writer raises: e.g. the error that stopped it, raised again by the commit)."""
        self._close(replace=True)

    def __exit__(self, *exc_info: Any) -> bool:
        """Leave a ``with`` block: `close` when it ended normally, and when an exception ends it `stop` (as `simreel
        record` does): the running episodes are noted as cut short and a recording that was to replace an old file
        (`overwrite`) stays in its side folder, the old file as it was. The exception goes on."""
        error = exc_info[1]
        if error is None:
            self.close()
        else:
            self.stop(what_stopped(error))
        return False

    def stop(self, reason: str) -> None:
        """End a recording stopped before it was complete (`reason`: what stopped it, e.g. "Ctrl-C (SIGINT)"): each
        running episode that has steps is committed with a note that it was cut short, and a recording that was to
        replace an old file (`overwrite`) stays in its side folder, the old file as it was (a reader of the old file
        says where the new one is in its `notes`, as `simreel inspect` does: `simreel.io.staging`). Then the env
        is closed, as by `close`."""
        for i, meta in enumerate(self._episodes):
            if meta is not None and not self._ended(i) and i not in self._refused:
                meta.notes.append(f"cut short: {reason} stopped the recording before this episode ended")
        self._close(replace=False)

    def _ended(self, i: int) -> bool:
        """Env i's last step ended its episode (terminated or truncated), as the step's captured scalars say."""
        captured = self._last_scalars
        if captured is None or self._sent[i] + self._buffer.pending(i) == 0:
            return False
        terminated, truncated = captured[1], captured[2]
        return any(bool(flags[i] if isinstance(flags, list) else flags) for flags in (terminated, truncated))

    def _close(self, *, replace: bool) -> None:
        """Commit the running episodes, close the writer and the env. An episode whose last steps the sink refuses
        is committed with the steps before them (`_refuse`), and the other envs' episodes too; the first refusal is
        raised once the file is closed."""
        refusal = None
        try:
            if not self._closed:
                self._closed = True
                try:
                    for i in range(self._n):
                        try:
                            self._finish(i)
                        except EpisodeLayoutError as e:  # its refused steps are taken: the rest commits now
                            refusal = refusal or e
                            self._finish(i)
                finally:
                    self._writer.close(replace=replace)
        finally:
            self.env.close()
        if refusal is not None:
            raise refusal

    def _check_open(self, call: str) -> None:
        if self._closed:
            raise UsageError(f"RecordWrapper.{call} after close(): the recording is closed; wrap the env in a new "
                             "RecordWrapper to record more")

    # ------------------------------------------------------------------ internals
    @property
    def path(self) -> Path:
        return self._writer.path

    def _bind_sampler(self) -> None:
        """Bind the contact sampler to the scene now (at the start and after a reset that rebuilt it); a rebuilt scene
        that lacks a body of the channels chosen from the first one is `StateLayoutError`."""
        try:
            self._sampler.bind(self._u)
        except KeyError as e:
            raise StateLayoutError(
                f"{self.meta.env_id}: this episode's scene has no body {e}, which the recording's contact channels name "
                "(chosen from the first scene, and the same for every episode); record without contacts "
                "(--contacts none, contacts=\"none\") or with pairs of bodies every scene has") from None
        self._contacts_captured = self._sampler.captures

    def _fingerprint_scenes(self, envs: Iterable[int]) -> None:
        """Where sub-scenes `envs` differ from the recording's scene fingerprint (after the scene was built or
        rebuilt; ~3 ms each, never per step): each of their episodes keeps it (`EpisodeMeta.scene_changes`)."""
        for i in envs:
            now = scene_fingerprint(self._u, env_idx=i)
            self._scene_changes[i] = fingerprint_changes(self.meta.scene_fingerprint, now)

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

    def _captures_generators(self, seed: Any) -> bool:
        """Whether a reset with `seed` draws its episode from generators that are not reseeded, in a way a replay can
        repeat once it has their states (`simreel.sim.generators`): one without a seed, enhanced determinism off, in
        a one-env recording (a replay resets one env at a time; with several, one draw serves them all)."""
        return seed is None and self._n == 1 and not getattr(self._u, "_enhanced_determinism", False)

    def _bind_fast_reader(self, state: dict[str, np.ndarray], reconfigured: bool) -> bytes | None:
        """Bind a fast state reader to the scene after a reset (a reconfiguring reset builds new bodies); the reader's
        capture of `state` where it is the scene's proven reader, kept (else None).

        A reader is checked bit for bit against `get_state_dict()` after the first step of an episode (`_state`; after
        a reset most velocities are zero, a weaker check), and any difference retires it. Once a scene's reader has
        passed that check, the readers of its later episodes are checked at their reset instead, against `state` (the
        reset row just read through `get_state_dict()`): one fast read rather than one more `get_state_dict()` per
        episode. A reader that differs there is rebuilt and checked after the first step again."""
        if self._fast_refuted:
            return None
        px = self._u.scene.px
        if reconfigured:
            self._fast_scene = None
        kept = self._fast is not None and self._fast.px is px and self._fast_scene is px
        packed = self._fast.capture_equal_to(state) if kept else None
        if packed is not None:  # the scene's proven reader, checked again
            self._fast_unchecked = False
            return packed
        self._fast = FastStateReader.for_env(self._u)
        self._fast_unchecked = self._fast is not None
        if self._fast is not None:
            self._state_rows = dataclasses.replace(self._fast.packed_rows, prefix="env_states/")
        return None

    def _check_state_layout(self, state: dict[str, np.ndarray], packed: bytes | None) -> dict[str, np.ndarray]:
        """Refuse a reset whose state (just read through `get_state_dict()`) is not in the recording's layout
        (`StateLayoutError` naming the leaves); returns the leaves of `state` that `packed`, the scene's proven reader's
        capture of it (`_bind_fast_reader`), does not hold: all of them without one. The leaves the capture holds
        need no check: they equal, bit for bit, those of the same reader at a reset whose layout was checked whole
        (when it was built); the others (controller targets, custom state) may change at any reset."""
        layout = self.meta.state_layout
        if packed is not None:
            held = self._fast.packed_keys
            state = {key: a for key, a in state.items() if key not in held}
            layout = {key: spec for key, spec in layout.items() if key not in held}
        check_same_layout(self.meta.env_id, layout, layout_of(state, batched=True))
        return state

    def _reset_rows(self, state: dict[str, np.ndarray], unpacked: dict[str, np.ndarray], obs: Any,
                    packed: bytes | None) -> tuple[dict[str, np.ndarray], tuple[tuple[Any, list[Any], int], ...]]:
        """The reset row of every env: (its fields, `StepBlock.captured`). Where the writer process converts captures
        and the proven reader captured `state` (`packed`, one env), the leaves it holds go as that capture (one byte
        string to send rather than an array per leaf), the rest (`unpacked`) as arrays."""
        if packed is None or not self._defer:
            return self._per_state_rows(state, obs), ()
        return self._per_state_rows(unpacked, obs), ((self._state_rows, [packed], 0),)

    def _state(self) -> tuple[dict[str, np.ndarray], bytes | None]:
        """The state after a step: (state leaves read now, the packed rest for `_state_rows` or None). Through the
        fast CPU reader where it is proven equal (`_bind_fast_reader`), else all of it through `get_state_dict()`."""
        if self._fast is None:
            return read_state(self._u), None
        if self._fast_unchecked:
            self._fast_unchecked = False
            if not self._fast.matches():
                self._fast, self._fast_refuted = None, True
                warnings.warn(f"simreel: the fast state reader disagrees with {self.meta.env_id}'s get_state_dict(); "
                              "recording through get_state_dict() from now on", RuntimeWarning, stacklevel=3)
                return read_state(self._u), None
            self._fast_scene = self._u.scene.px
        packed = self._fast.capture()
        if packed is None:  # bodies were added or removed since the reader was built
            return read_state(self._u), None
        return self._fast.extras(), packed

    def _flush(self, i: int) -> None:
        """Hand env i's buffered steps to its episode's sink. Callers hold signals (`deferred_signals`): a Ctrl-C
        between taking the rows and handing them over would lose them."""
        sink = self._sinks[i]
        block = None if sink is None else self._take(i)
        if block is not None:
            sink.append(block)
            self._sent[i], self._success[i], self._ever_success[i] = self._with_block(i, block)

    def _take(self, i: int) -> StepBlock | None:
        """Env i's buffered steps not yet handed to its episode's sink (None: none); the caller hands them over."""
        return self._buffer.take(i, defer=self._defer) if self._buffer.pending(i) else None

    def _with_block(self, i: int, block: StepBlock | None) -> tuple[int, bool, bool]:
        """Env i's episode as it stands with `block` handed over too: (its length, whether its last step succeeded,
        whether any did). Noted once the sink has taken the block: one it refused is not in the file."""
        if block is None:
            return self._sent[i], bool(self._success[i]), bool(self._ever_success[i])
        last, any_success = self._success_flags(block)
        return self._sent[i] + block.rows, last, bool(self._ever_success[i]) or any_success

    def _success_flags(self, block: StepBlock) -> tuple[bool, bool]:
        """Whether `block`'s last step succeeded, and whether any did, also where its flags are still captured
        (`StepBuffer.take`)."""
        for source, captures, env in block.captured:
            if source is self._scalars.rows:
                return source.last_and_any(captures, "success", env)
        success = block["success"]
        return bool(success[-1]), bool(success.any())

    def _finish(self, i: int) -> None:
        """End env i's episode: commit it with the steps it has (discard it with none). Signals are held throughout,
        so an ended episode is always committed or discarded, never left to neither. Where the sink refuses the last
        steps (a block that breaks the layout: the error goes on), the episode stays running without them, stopped
        there (`_refuse`), and the next reset, `stop` or `close` commits it with the steps handed over before."""
        with deferred_signals():
            sink, meta = self._sinks[i], self._episodes[i]
            if sink is None:
                return
            last = self._take(i)
            meta.length, success, ever_success = self._with_block(i, last)
            if self._has_success:
                meta.success, meta.ever_success = success, ever_success
            if meta.length:
                try:
                    sink.finish(meta, last)
                except EpisodeLayoutError as e:
                    self._refuse(i, f"the writer refused the steps from there on ({e})")
                    raise
                self._chain_ran[i] += 1
            self._sinks[i] = None
            self._episodes[i] = None
            self._refused.pop(i, None)
            self._open -= 1
            if not meta.length:
                sink.discard()


def what_stopped(error: BaseException) -> str:
    """What stopped a recording, for the note on each episode it cut short (`RecordWrapper.stop`)."""
    if isinstance(error, Terminated):
        return "SIGTERM"
    if isinstance(error, KeyboardInterrupt):
        return "Ctrl-C (SIGINT)"
    return f"an error ({error})" if isinstance(error, SimreelError) else f"an error ({type(error).__name__})"


def _reset_options(options: Any) -> dict[str, Any]:
    """`reset()`'s options as a dict of its own (None: none); `UsageError` for anything but a dict."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise UsageError(f"reset(options={options!r}): give a dict of reset options, e.g. {{'env_idx': [0]}} or "
                         "{'reconfigure': True}")
    return dict(options)


def _seed_list(seed: Any) -> list[Any] | None:
    """The seeds of `reset(seed=...)` given as a list, a tuple, an array or a tensor (one value each), or None for
    anything else, a single seed or not one at all."""
    if isinstance(seed, (list, tuple)):
        return list(seed)
    if hasattr(seed, "dtype") and hasattr(seed, "shape"):
        return to_numpy(seed).reshape(-1).tolist()
    return None


def _constructor_options(opts: RecordOptions) -> dict[str, Any]:
    """The options that differ from the defaults, as plain values for ``env.spec`` (gymnasium's WrapperSpec)."""
    default = RecordOptions()
    out = {}
    for f in dataclasses.fields(opts):
        value = getattr(opts, f.name)
        if value != getattr(default, f.name):
            out[f.name] = list(value) if isinstance(value, tuple) else dict(value) if isinstance(value, Mapping) else value
    return out
