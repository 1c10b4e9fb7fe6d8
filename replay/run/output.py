"""`ReplayedWriter`: writes replayed episodes (``simreel replay -o``) as a simreel recording, in the order they
were asked for, whatever order the workers finish them in. The episode that is next in that order and replayed in
this process is written block by block as it is replayed (`ReplayedWriter.stream`: an `EpisodeStream`). Any other
one — replayed in a pool's worker process, or here while an earlier one is not written yet — is written block by
block to a scratch recording of its own (`ScratchEpisode`, in the run's `ScratchFolder` beside the output); its
path waits for its turn (`put`), and is then copied into the output a block of rows at a time and deleted. No
process holds more than a block of a long episode. (A Ray actor's episode comes back whole.) `simreel convert`
writes its converted episodes the same way."""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import shutil
import sys
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from simreel.errors import SimreelError, StorageError, UsageError
from simreel.formats import EpisodeSink, format_of
from simreel.io.durable import raise_if_stopped
from simreel.io.lock import WriterLock, being_written
from simreel.model.blocks import StepBlock
from simreel.model.episode import Episode
from simreel.model.fields import OPTIONAL_STEP_FIELDS
from simreel.model.meta import EpisodeMeta, RecordingMeta, new_recording_id
from simreel.model.state_tree import layout_of
from simreel.replay.run.sinks import BlockSink

__all__ = ["ReplayOutput", "ReplayedWriter", "EpisodeStream", "RecordedContacts", "output_pose_bodies",
           "ScratchFolder", "ScratchEpisode", "scratch_folder", "OutputFailed", "published", "staged_path",
           "publish_checked"]

_PRODUCED = ("versions", *OPTIONAL_STEP_FIELDS)
"""What a replay knows even where the recording did not hold it: this machine's versions, rewards and flags."""


@dataclasses.dataclass(frozen=True)
class ReplayOutput:
    """Where and what `-o` writes: the file, whether it may replace one, the replay's observation mode, the
    bodies whose poses it holds, and the command line kept as provenance."""

    path: str
    overwrite: bool = False
    obs_mode: str | None = None
    pose_bodies: tuple[str, ...] = ()
    command: str = ""
    changes: dict[str, Any] = dataclasses.field(default_factory=dict)
    """`RecordingMeta` fields to set in the output (a conversion: control mode, action space, provenance)."""


class OutputFailed(Exception):
    """The output could not be written (a full disk, a read-only folder, ...), met while an episode was replayed into
    it. Not a `SimreelError`, so a worker does not report it as that episode's error and go on: it stops the run,
    whose output is then dropped (`published`), and the run raises `error`, the writer's own."""

    def __init__(self, error: SimreelError) -> None:
        super().__init__(error)
        self.error = error


@contextlib.contextmanager
def _writing_output() -> Iterator[None]:
    """Raise the errors of writing the output as `OutputFailed`."""
    try:
        yield
    except SimreelError as e:
        raise OutputFailed(e) from e


@contextlib.contextmanager
def published(writer: ReplayedWriter, keep: Callable[[], bool] = lambda: True,
              final: str | Path | None = None) -> Iterator[ReplayedWriter]:
    """Run the block that writes `writer`'s episodes, then publish the output (`close`) if `keep()`, else drop it.
    When the block raises — an error that stops the run, the output's own (`OutputFailed`: raised as the writer's
    error), Ctrl-C or SIGTERM — the output is dropped (`abort`): no part of a run is published, and an old file the
    output was to replace stays as it was. `final`: the output's name when `writer` writes it in the run's scratch
    folder first (`publish_checked` moves it there), for the messages."""
    try:
        yield writer
        raise_if_stopped()  # a Ctrl-C that landed in a finalizer (h5py's) was printed and dropped by Python
        if keep():
            writer.close()  # a close that fails (the disk full at the end of the file) drops the output too
        else:
            writer.abort()
    except BaseException as e:
        writer.abort()
        error = e.error if isinstance(e, OutputFailed) else e
        if isinstance(error, StorageError):
            out = str(final or writer.spec.path)
            named = out if Path(error.path).parent == scratch_folder(out) else error.path  # not a hidden scratch file
            error = error.dropped(f"; nothing was written to {out}", named)
        if error is e:
            raise
        raise error from None


def staged_path(scratch: ScratchFolder) -> Path:
    """Where a run that checks its output before publishing it (`publish_checked`) writes it: in its scratch folder,
    under a name no `ScratchEpisode` takes, with the output's suffix (its format)."""
    return scratch.path / f"output{scratch.output.suffix}"


def publish_checked(staged: Path, final: str | Path, meta: RecordingMeta, *, overwrite: bool) -> None:
    """Move the complete, checked recording `staged` and its side files to `final`, as `simreel merge` publishes its
    outputs (`simreel.datasets.staged`, one copy of the rule): its side files first, without `overwrite` never over a
    file that appeared there meanwhile, never over a recording another process is writing now, and with SIGINT and
    SIGTERM held until every file is moved. An old recording at `final` stays whole until then."""
    from simreel.datasets.staged import StagedOutput, Target, publish_outputs

    publish_outputs([StagedOutput(Target(Path(final), meta, overwrite), Target(staged, meta, True))])


def output_pose_bodies(meta: RecordingMeta, output: str | Path | None) -> tuple[str, ...]:
    """Bodies whose poses `-o` writes: those the recording has, or every body when writing MCAP (its transforms)."""
    if output is None:
        return ()
    if meta.pose_bodies:
        return tuple(meta.pose_bodies)
    if format_of(output) != "mcap":
        return ()
    scene = meta.scene or {}
    names = list(scene.get("actors", {}))
    for art, desc in scene.get("articulations", {}).items():
        names += [f"{art}/{link}" for link in desc.get("links", [])]
    return tuple(names)


class ReplayedWriter:
    """Writes replayed episodes to `spec.path` in `order`; the output's metadata is the recording's `meta` with
    the replay's observation layout, contact channels and poses, this machine's versions and the command."""

    def __init__(self, spec: ReplayOutput, meta: RecordingMeta, order: list[int]) -> None:
        self.spec = spec
        self.meta = meta
        self.order = deque(order)
        self.waiting: dict[int, Episode | Path | None] = {}
        """Episodes replayed before their turn: a scratch recording's path (`ScratchEpisode`), or a whole episode."""
        self.writer: Any = None

    def put(self, index: int, episode: Episode | Path | None) -> None:
        """Write episode `index` once those before it in the order are written: a whole episode, or the scratch
        recording at a path (copied a block at a time, then deleted); None: it has no replay (it could not be
        replayed, or it was streamed), go on without it."""
        self.waiting[index] = episode
        while self.order and self.order[0] in self.waiting:
            replayed = self.waiting.pop(self.order.popleft())
            if isinstance(replayed, Path):
                self._copy(replayed)
            elif replayed is not None:
                self._write(replayed)

    def stream(self, meta: EpisodeMeta) -> EpisodeStream | None:
        """A sink writing the episode of `meta` block by block as it is replayed, when it is the next one to write
        (else None: its replay must wait for its turn whole, `put`). Its result is then `put` as None."""
        if not self.order or self.order[0] != meta.index or self.waiting:
            return None
        return EpisodeStream(self, meta)

    def _output_meta(self, fields: Mapping[str, np.ndarray]) -> RecordingMeta:
        """The output's metadata, from the replayed fields of its first episode (any rows of them)."""
        from simreel.sim.make import env_versions

        obs = {k[len("obs/"):]: a for k, a in fields.items() if k.startswith("obs/")}
        fields = {
            "obs_mode": self.spec.obs_mode or self.meta.obs_mode,
            "obs_layout": layout_of(obs, batched=True) if obs else {},
            "contact_channels": list(self.meta.contact_channels) if "contact_forces" in fields else [],
            "pose_bodies": list(self.spec.pose_bodies) if "body_poses" in fields else [],
            "versions": {k: v for k, v in env_versions().items() if v is not None},
            "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "command": self.spec.command,
            "recording_id": new_recording_id(),
            "unknown": [u for u in self.meta.unknown if u not in _PRODUCED],
        }
        return dataclasses.replace(self.meta, **{**fields, **self.spec.changes})

    def begin(self, meta: EpisodeMeta, reset: StepBlock, first: StepBlock | None) -> EpisodeSink:
        """Begin writing an episode with replayed `reset` row (the writer opened with the layout of it and of its
        `first` block of steps, if the writer is not open yet)."""
        from simreel.formats import open_writer

        if self.writer is None:
            fields = {**(first.arrays if first is not None else {}), **reset.arrays}
            self.writer = open_writer(self.spec.path, self._output_meta(fields), overwrite=self.spec.overwrite)
        return self.writer.begin_episode(meta, reset)

    def _write(self, episode: Episode) -> None:
        ep_meta = dataclasses.replace(episode.meta, length=episode.length)
        if episode.length:
            ep_meta.success = bool(episode.success[-1])
            ep_meta.ever_success = bool(np.any(episode.success))
        episode.check_shapes()
        sink = self.begin(ep_meta, episode.reset_block(), episode.steps_block())
        if episode.length:
            sink.append(episode.steps_block())
        sink.commit(ep_meta)

    def _copy(self, path: Path) -> None:
        """Write the one episode of the scratch recording `path` (a `ScratchEpisode`'s, committed with its final
        metadata) a block of rows at a time, then delete the scratch recording."""
        from simreel.formats import open_reader, remove_recording

        with open_reader(path) as reader:
            (meta,) = reader.episodes
            rows = reader.open_episode(meta.index)
            blocks = rows.blocks()
            block = next(blocks, None)
            sink = self.begin(meta, rows.reset(), block[1] if block else None)
            while block is not None:
                sink.append(block[1])
                block = next(blocks, None)
            sink.commit(meta)
        remove_recording(path)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()

    def abort(self) -> None:
        """Drop the output instead of finishing it (`EpisodeWriter.abort`: an old file it was to replace stays)."""
        if self.writer is not None:
            self.writer.abort()
            self.writer = None


class EpisodeStream(BlockSink):
    """Writes one replayed episode to the output as its blocks are replayed; `commit` with the verdict, or `discard`
    (an error stopped the replay: nothing of the episode stays)."""

    def __init__(self, output: ReplayedWriter, meta: EpisodeMeta) -> None:
        self.output = output
        self.meta = meta
        """The recorded episode's metadata, which the episode begins with (its final one comes with `commit`)."""
        self._sink: EpisodeSink | None = None
        self.start()

    def start(self) -> None:
        self.discard()
        self._reset: StepBlock | None = None
        self._success: tuple[bool, bool] | None = None  # (last, ever)

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self._reset = replayed

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        with _writing_output():
            if self._sink is None:
                assert self._reset is not None
                self._sink = self.output.begin(self.meta, self._reset, replayed)
            self._sink.append(replayed)
        if replayed.rows:
            ever = bool(np.any(replayed["success"])) or (self._success is not None and self._success[1])
            self._success = (bool(replayed["success"][-1]), ever)

    def commit(self, meta: EpisodeMeta, length: int) -> None:
        """Make the episode durable with `meta` (its length and success set from what was written)."""
        meta = dataclasses.replace(meta, length=length)
        if self._success is not None:
            meta.success, meta.ever_success = self._success
        with _writing_output():
            if self._sink is None:
                assert self._reset is not None
                self._sink = self.output.begin(meta, self._reset, None)
            self._sink.commit(meta)
        self._sink = None

    def discard(self) -> None:
        """Drop what was written of the episode. Called while an error or Ctrl-C is handled (the caller then raises
        it again), an output that fails here never hides that: its failure (`OutputFailed`) is raised only over an
        episode's own error (a `SimreelError`, after which the run would go on into the broken output)."""
        in_flight = sys.exc_info()[1]
        sink, self._sink = self._sink, None
        if sink is None:
            return
        try:
            with _writing_output():
                sink.discard()
        except OutputFailed:
            if in_flight is None or isinstance(in_flight, SimreelError):
                raise


def scratch_folder(output: str | Path) -> Path:
    """The hidden folder beside the output `output` where a run's scratch recordings go (`out.h5` →
    `.out.h5.replay.partial`: on the output's file system, so a copy never crosses disks; skipped by the folder
    searches of `replay`/`inspect`, as every `.partial` folder is)."""
    output = Path(output)
    return output.with_name(f".{output.name}.replay.partial")


class ScratchFolder:
    """The run's `scratch_folder`, held for as long as the run (a context manager): created empty when it starts,
    removed with everything in it when it ends, however it ends (done, an error, Ctrl-C). A folder left by a run
    that was killed (-9: nothing could remove it) holds only replays that run never finished; the next run writing
    the same output removes it. One held by a live run (its lock) is refused with one line."""

    def __init__(self, output: str | Path) -> None:
        self.output = Path(output)
        self.path = scratch_folder(output)
        self._lock: WriterLock | None = None

    def __enter__(self) -> ScratchFolder:
        lock = self.path / "lock"
        busy = UsageError(f"{self.output} is being written by another replay or conversion (it holds {self.path}); "
                          "choose another output, or wait until that run has finished")
        if being_written(lock):
            raise busy
        shutil.rmtree(self.path, ignore_errors=True)  # a killed run's leftovers
        try:
            self.path.mkdir()
            self._lock = WriterLock.acquire(lock, create=True)
        except FileExistsError:  # another run claimed it between the check and here
            raise busy from None
        except OSError as e:
            raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
        return self

    def __exit__(self, *exc: object) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
        if self._lock is not None:
            self._lock.release()
            self._lock = None


class ScratchEpisode(EpisodeStream):
    """One replayed episode written as it is replayed to a recording of its own in the run's scratch folder: the
    output's metadata and field table (`spec` as the output's, with the scratch path), committed with the episode's
    final metadata (verdict included), so that `ReplayedWriter` copies it into the output as if it were streamed
    there. `discard` (the replay failed or was stopped) removes it."""

    def __init__(self, folder: Path, spec: ReplayOutput, meta: RecordingMeta, episode: EpisodeMeta) -> None:
        self.path = folder / f"episode_{episode.index}.h5"
        scratch = dataclasses.replace(spec, path=str(self.path), overwrite=False, command="")
        super().__init__(ReplayedWriter(scratch, meta, [episode.index]), episode)

    def commit(self, meta: EpisodeMeta, length: int) -> None:
        super().commit(meta, length)
        with _writing_output():
            self.output.close()

    def discard(self) -> None:
        super().discard()
        if self.output.writer is not None:
            self.output.writer.abort()
            self.output.writer = None


class RecordedContacts(BlockSink):
    """Hands replayed blocks on to `then` with the recorded contact forces in place of the replayed ones: in ``states``
    mode the states were restored from the recording, so its contact forces are the true ones of the original run
    (the replay's come from one step simulated from each restored state)."""

    def __init__(self, then: BlockSink) -> None:
        self.then = then

    def start(self) -> None:
        self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.then.reset(recorded, replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        arrays = {k: a for k, a in replayed.arrays.items() if k != "contact_forces"}
        if recorded.get("contact_forces") is not None:
            arrays["contact_forces"] = recorded["contact_forces"]
        self.then.steps(first, recorded, StepBlock(arrays, replayed.rows))
