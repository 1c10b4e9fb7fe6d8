"""`RecordWrapper`: records a ManiSkill env's episodes, with full state dicts and contacts, to a file.

Every parallel env's episode is its own episode on disk. An episode runs from a reset of its env to
the next reset of that env (a partial reset `options={"env_idx": [...]}` ends only those envs'
episodes) or to `close()`. Steps are buffered in blocks of `block_steps` and streamed to the writer,
so memory does not grow with episode length. The writer runs in a child process (`simreel.recorders.writer_process`)
and commits the episodes a reset ends while the env resets; `reset()` returns once they are durable. After
each step the recorder copies out what it needs and converts a block of steps at once (`StepBuffer`):
right after a physics step every numpy call costs several times its usual price.

The wrapper holds the gym API and the episodes it has begun; what it asks of a reset (`reset_args`), how it reads the
state (`state_capture`), what it notes of each sub-scene (`scene_book`) and its options (`options`) are modules of
their own.
"""

from __future__ import annotations

import contextlib
import json
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from simreel.errors import EpisodeLayoutError, SimreelError, StateLayoutError, Terminated, UsageError
from simreel.formats import check_writer_options, open_writer, records_poses_by_default, writes_scene
from simreel.io.durable import deferred_signals
from simreel.model.blocks import StepBlock
from simreel.model.fields import episode_fields
from simreel.model.meta import EpisodeMeta, json_default
from simreel.model.state_tree import LeafSpec, layout_differences, layout_of, to_numpy
from simreel.options.checks import options_with, path_text
from simreel.recorders.options import RecordOptions, constructor_options
from simreel.recorders.reset_args import (
    check_seeds,
    draws_from_generators,
    envs_to_reset,
    episode_seeds,
    remade_by_replay,
    reset_options,
    unseeded_warning,
)
from simreel.recorders.scene_book import SceneBook
from simreel.recorders.scene_drawing import SceneDrawing
from simreel.recorders.state_capture import StateCapture
from simreel.recorders.step_buffer import StepBuffer
from simreel.recorders.step_scalars import StepScalars, scalar_info
from simreel.recorders.wrapper_policy import refuse_reshaping_wrappers
from simreel.recorders.writer_process import ProcessWriter
from simreel.sim.actions import ActionCheck
from simreel.sim.contacts import ContactSampler, contact_channels
from simreel.sim.describe import flatten_obs, recording_meta
from simreel.sim.generators import capture_generators, consumed_generators
from simreel.sim.poses import pose_body_names, sample_body_poses
from simreel.sim.step_rows import ActionRows
from simreel.sim.user_code import found_spec

__all__ = ["RecordWrapper", "RecordOptions", "what_stopped"]


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
        gym.utils.RecordConstructorArgs.__init__(self, path=str(path), **constructor_options(opts))
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
        self.meta = self._describe(env, path)  # refuses an action space other than a Box
        self._capture = StateCapture(u, self.meta)
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
        self.unseeded = 0
        """Episodes begun by a reset without a seed (an RL loop's), so far."""
        self.unseeded_remade = 0
        """Of those, the episodes whose reset a replay remakes exactly (their random generators' states captured)."""
        self._warned_unseeded = False
        self._scenes = SceneBook(u, self.meta)
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
        options = reset_options(options)
        idxs = envs_to_reset(options.get("env_idx"), self._n)
        check_seeds(seed, idxs, self._n)
        for i in idxs:
            self._finish(i)
        if self._buffer.rows and all(s is None for s in self._sinks):
            self._buffer.rewind()
        self._writer.checkpoint()  # a writer process commits the episodes just ended while the env resets
        before = capture_generators(self._u) if draws_from_generators(self._u, seed) else None
        obs, info = self.env.reset(seed=seed, options=options or None)
        generators = consumed_generators(before, self._u) if before is not None else {}
        reconfigured = bool(to_numpy(info.get("reconfigure", False)).any()) if "reconfigure" in info else False
        state, unpacked, packed = self._capture.at_reset(reconfigured)
        if reconfigured or self._sampler.px is not self._u.scene.px:
            self._bind_sampler()
        reset_rows, captured = self._reset_rows(state, unpacked, obs, packed)
        stored_options = json.loads(json.dumps({k: v for k, v in options.items() if k != "env_idx"},
                                               default=json_default))
        if reconfigured:
            self._scenes.rebuilt(range(self._n))
            self._drawing.send(range(self._n))
        seeds = episode_seeds(self._u, seed, idxs)
        self._note_unseeded(seeds, generators)
        for i, seed_i in zip(idxs, seeds, strict=True):
            scene = self._scenes.begin(i, self._next_index, reconfigured, seed_i)
            meta = EpisodeMeta(index=self._next_index, seed=seed_i, reset_options=stored_options, env_idx=i,
                               reconfigured=reconfigured, **scene._asdict(),
                               reset_generators=dict(generators))
            self._start(i, meta, StepBlock({k: a[i : i + 1] for k, a in reset_rows.items()}, 1, captured))
        self._settle()
        return obs, info

    def _note_unseeded(self, seeds: list[int | None], generators: dict[str, str]) -> None:
        """Count the episodes this reset began without a seed (`unseeded`) and those a replay remakes (their
        generators captured: `unseeded_remade`); warn once when a replay cannot remake them."""
        count = sum(s is None for s in seeds)
        if not count:
            return
        self.unseeded += count
        if remade_by_replay(self._u, generators):
            self.unseeded_remade += count
        elif not self._warned_unseeded:
            self._warned_unseeded = True
            warnings.warn(unseeded_warning(self._u), stacklevel=3)

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
        state, packed = self._capture.after_step()
        if packed is not None:
            captures.append((self._capture.rows, packed))
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

    def _reset_rows(self, state: dict[str, np.ndarray], unpacked: dict[str, np.ndarray], obs: Any,
                    packed: bytes | None) -> tuple[dict[str, np.ndarray], tuple[tuple[Any, list[Any], int], ...]]:
        """The reset row of every env: (its fields, `StepBlock.captured`). Where the writer process converts captures
        and the proven reader captured `state` (`packed`, one env), the leaves it holds go as that capture (one byte
        string to send rather than an array per leaf), the rest (`unpacked`) as arrays."""
        if packed is None or not self._defer:
            return self._per_state_rows(state, obs), ()
        return self._per_state_rows(unpacked, obs), ((self._capture.rows, [packed], 0),)

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
                self._scenes.committed(i)
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
