"""Where episodes are replayed: a `ReplayWorker` (readers and one rebuilt env) in this process, and one in each
worker process of a pool (`run_pool`), each replaying episodes of any file of the run, a block of rows at a time,
and answering with an `EpisodeResult`.

A worker keeps the env it built for the last env key (`simreel.replay.run.worklist.env_key`) and rebuilds only when
the key changes; the work list is ordered by key so that is rare. In mode ``actions`` it also keeps what its env's
scene ran since it was built (`SceneRun`), and before an episode replays the episodes that ran before it in the
recorder's scene (`simreel.verdicts.scene_history`) which its scene has not run, rebuilding the scene first when it ran
anything else: PhysX's CPU results depend on that history. A `ReplayJob` is everything a worker needs,
picklable so that worker processes (started with ``spawn``: sapien/torch state must not be forked) and Ray
actors can build their own.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import socket
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simreel.errors import EPISODE_DATA_ERRORS, ReplayError, SimreelError
from simreel.formats import EpisodeReader, open_reader
from simreel.formats.base import EpisodeRows
from simreel.io.processes import launched, setup_worker_process, spawn_context
from simreel.model.blocks import StepBlock
from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.lineage import ScenePlace
from simreel.model.meta import ContactChannel, EpisodeMeta, RecordingMeta
from simreel.replay.explain.explain import ExplainContext, explain_divergence
from simreel.replay.report.report import EpisodeReport
from simreel.replay.run.engine import (
    RESTORING_MODES,
    BlockSink,
    Collected,
    EpisodeReplayer,
    ReplayedEpisode,
    ReplayerOptions,
)
from simreel.replay.run.history import (
    SHIPPED_HISTORY,
    ReplayedHistory,
    SceneRun,
    describe_missing_history,
    describe_missing_step_before,
    describe_unreadable_history,
    has_history,
    last_step_history,
    restoring_history,
    span,
    step_before,
    whole_history_after,
)
from simreel.replay.run.output import (
    EpisodeStream,
    RecordedContacts,
    ReplayedWriter,
    ReplayOutput,
    ScratchEpisode,
    output_pose_bodies,
)
from simreel.replay.run.worklist import WorkItem, chain_groups, next_item
from simreel.sim.user_code import resolve_task_imports
from simreel.verdicts.compare import BlockComparison, CompareScope, EpisodeComparison
from simreel.verdicts.scene_history import SceneChains

__all__ = ["ReplayJob", "ReplayWorker", "EpisodeResult", "VerifySink", "run_pool", "start_pool", "Lanes",
           "pool_closing", "WorkerDiedError"]

_OPEN_READERS = 8
"""Recordings a worker keeps open (the work list visits files in turn, so few are ever needed again)."""


@dataclass(frozen=True)
class ReplayJob:
    """What every worker of one run does with an episode: mode, tolerances, and how to build the env."""

    mode: str
    resync: int | None
    tolerances: Tolerances
    obs_mode: str | None = None
    sim_backend: str | None = None
    output: str | None = None
    """Where the replayed episodes go (`-o`): workers then write them (or return them), with the bodies' poses it
    needs."""
    scratch: str | None = None
    """With `output`: the run's scratch folder (`simreel.replay.run.output.ScratchFolder`), where a worker writes, as
    it replays it, each episode it cannot write into the output itself (`ScratchEpisode`), and returns its path.
    None: such an episode is collected whole and returned (a Ray actor, which may not share this file system)."""
    imports: tuple[str, ...] = ()
    """`--import` specs given now: used instead of the recorded ones (`resolve_task_imports`)."""
    trust_imports: bool = False
    """``--trust-recorded-imports``: the recorded ones may be imported (`resolve_task_imports`)."""
    block_rows: int | None = None
    """Steps read, replayed and compared at a time (None: the reader's `simreel.formats.base.block_rows`)."""

    def replayer_options(self, meta: RecordingMeta) -> ReplayerOptions:
        """How to build the env replaying the recording with `meta`."""
        need_obs = bool(meta.obs_layout) or self.obs_mode is not None
        need_rewards = "rewards" not in meta.unknown or self.output is not None
        return ReplayerOptions(obs_mode=self.obs_mode, need_obs=need_obs, need_rewards=need_rewards,
                               sim_backend=self.sim_backend, pose_bodies=output_pose_bodies(meta, self.output))

    def meta_for(self, meta: RecordingMeta, path: str) -> RecordingMeta:
        """The metadata of the recording at `path` with its task's code found: the job's `--import`s, else the
        recorded ones, looked for where `resolve_task_imports` looks."""
        return dataclasses.replace(meta, imports=resolve_task_imports(meta.imports, explicit=self.imports,
                                                                      recording=path, trust=self.trust_imports))

    def open_worker(self) -> ReplayWorker:
        """The worker a pool process runs this job in (`run_pool` calls it in each process)."""
        return ReplayWorker(self)


@dataclass
class EpisodeResult:
    """What replaying one work item gave: its report (and for `-o` the scratch recording of the replay, or the
    replayed arrays), or the user error that stopped it (an unreadable episode, an env that does not build),
    which the caller reports or raises."""

    item: WorkItem
    report: EpisodeReport | None = None
    episode: Episode | None = None
    """The replayed episode, whole: only where the job has no scratch folder (Ray)."""
    scratch: Path | None = None
    """The scratch recording holding the replayed episode (`ReplayJob.scratch`), for `ReplayedWriter.put`."""
    history: list[int] = field(default_factory=list)
    """Episodes of the item's file replayed (actions only, not verified) before it, to give its scene the history
    it had when recorded (`simreel.verdicts.scene_history`); empty when the scene had it already."""
    warnings: list[str] = field(default_factory=list)
    """What differs between the recording's machine and this one (`simreel.replay.run.fingerprint`); given with the
    first result of each file a worker replays."""
    error: SimreelError | None = None
    worker: str = ""
    """Which process replayed it: host and pid (and Ray node)."""

    @property
    def env_error(self) -> bool:
        """The error is about the file's env, not this episode's data: the file's other episodes fail alike."""
        return self.error is not None and not isinstance(self.error, EPISODE_DATA_ERRORS)


class VerifySink(BlockSink):
    """Compares each replayed block with its recorded one as it comes (`simreel.verdicts.compare.BlockComparison`), and hands
    both on to `then` (the `-o` output, or a `Collected` replay) when given."""

    def __init__(self, tolerances: Tolerances, channels: list[ContactChannel], scope: CompareScope,
                 then: BlockSink | None) -> None:
        self._args = (tolerances, channels, scope)
        self.then = then
        self.explain = True
        """Whether a divergence is explained (`ReplayWorker._report`)."""
        self.start()

    def start(self) -> None:
        tolerances, channels, scope = self._args
        self.blocks = BlockComparison(tolerances, channels=channels, scope=scope)
        if self.then is not None:
            self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.reset(recorded, replayed)
        if self.then is not None:
            self.then.reset(recorded, replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.steps(recorded, replayed)
        if self.then is not None:
            self.then.steps(first, recorded, replayed)

    def info_not_returned(self, keys: list[str]) -> None:
        self.blocks.info_not_returned(keys)
        if self.then is not None:
            self.then.info_not_returned(keys)

    def comparison(self) -> EpisodeComparison:
        return self.blocks.comparison()


class ReaderCache:
    """The recordings a process has open, the `_OPEN_READERS` last used: a work list ordered by env key meets each
    file in runs, and thousands of files must not mean thousands of open handles."""

    def __init__(self) -> None:
        self._readers: OrderedDict[str, EpisodeReader] = OrderedDict()

    def get(self, path: str) -> EpisodeReader:
        reader = self._readers.get(path)
        if reader is None:
            reader = self._readers[path] = open_reader(path)
            if len(self._readers) > _OPEN_READERS:
                self._readers.popitem(last=False)[1].close()
        self._readers.move_to_end(path)
        return reader

    def __len__(self) -> int:
        return len(self._readers)

    def close(self) -> None:
        while self._readers:
            self._readers.popitem()[1].close()


class ReplayWorker:
    """Replays work items of any file of a run: one process's readers and its one env (per env key)."""

    def __init__(self, job: ReplayJob) -> None:
        self.job = job
        self._readers = ReaderCache()
        self._key: str | None = None
        self._replayer: EpisodeReplayer | None = None
        self._failed: dict[str, SimreelError] = {}
        """Env keys whose env could not be built, with why: their other episodes fail at once, the same way."""
        self._warned: set[str] = set()
        self._scene: SceneRun | None = None
        """What the env's scene ran since it was built (None: unknown, e.g. after a failed or explained replay)."""
        self._chains: tuple[str, SceneChains] | None = None
        """The episode chains of the file last replayed (`_chains_of`)."""
        self.output: ReplayedWriter | None = None
        """The `-o` output when this process writes it: the episode next in its order is written as it is replayed."""
        self.where = f"{socket.gethostname()} pid {os.getpid()}"
        """Which process replays: what each result names as its worker."""

    def run(self, item: WorkItem, shipped: EpisodeReader | None = None) -> EpisodeResult:
        """Replay and verify `item`, read from its file or from `shipped` (the episode, sent where the file is not);
        a `SimreelError` comes back in the result, never raised."""
        where = self.where
        try:
            reader = shipped if shipped is not None else self._readers.get(item.path)
            replayer = self._replayer_for(item, reader.meta)
            scene, self._scene = self._scene, None  # unknown until the replay ends well
            history = self._replay_history(reader, replayer, item, scene, shipped=shipped is not None)
            report, replayed = self._replay(reader, replayer, item.index, history, self._ran_in(item, reader, history))
            if report.verdict != "exact" and history.short:  # the short history was not enough: the whole one
                history = self._whole_history(reader, replayer, item, whole_history_after(
                    self._previous(reader, item), report.verdict, _first(report)))
                report, replayed = self._replay(reader, replayer, item.index, history,
                                                self._ran_in(item, reader, history))
        except SimreelError as e:
            return EpisodeResult(item, error=e, worker=where)
        restoring = self.job.mode in RESTORING_MODES  # (what it ran last counts, not what ran before it)
        if not restoring:
            report.history = history.entry(shipped is None and not self._chains_of(item.path, reader).ran_before.get(
                item.index, 1))
        if report.explanation is None and shipped is None and (restoring or history.lost is None):
            chains = self._chains_of(item.path, reader)  # (an explanation steps again; a lost history ran none)
            self._scene = SceneRun.after(item.path, chains, item.index, short=history.short)
        episode, scratch = (None, replayed) if isinstance(replayed, Path) else (replayed, None)
        return EpisodeResult(item, report, episode, scratch=scratch, worker=where, history=history.replayed,
                             warnings=self._warnings(item.path, reader, replayer))

    def _replay_history(self, reader: EpisodeReader, replayer: EpisodeReplayer, item: WorkItem,
                        scene: SceneRun | None, *, shipped: bool) -> ReplayedHistory:
        """In mode ``actions``, give `replayer`'s scene (which ran `scene`) the history episode `item.index` had
        when recorded (`simreel.verdicts.scene_history.SceneChains`). Where it lacks more than one predecessor, only the
        last step of the one right before is replayed, from its recorded state, on a rebuilt scene (`_last_step`):
        a reset keeps of the scene's history what that step leaves, and the episode is kept if it then replays
        exact; `run` replays the whole history where it does not. Else the predecessors it lacks are replayed
        (actions only, nothing compared or written), after rebuilding the scene when it ran anything else. The other
        modes restore recorded states: no history is replayed, only the step before the reset (`_step_before`).
        Where the history cannot be replayed (a `shipped` episode comes without its file; a predecessor's data is
        damaged) the episode is replayed on a rebuilt scene without it, and its report says so."""
        if self.job.mode in RESTORING_MODES:
            return self._step_before(reader, replayer, item, scene, shipped=shipped)
        episode = reader.episode_meta(item.index)
        if shipped:
            replayer.forget_scene()  # a rebuilt scene at least: the same replay on every actor
            return ReplayedHistory(lost=SHIPPED_HISTORY if has_history(episode) else None)
        chains = self._chains_of(item.path, reader)
        if not chains.complete(item.index):
            replayer.forget_scene()
            lost = describe_missing_history(episode, chains.ran_before[item.index], reader.meta.recording_id)
            return ReplayedHistory(lost=lost)
        done = scene.ran_of(item.path, chains, item.index) if scene is not None else None
        missing = chains.history(item.index, since=done or 0)
        if len(missing) > 1:
            fresh = scene is not None and not scene.ran  # (fresh from gym.make: no rebuild needed)
            short = self._last_step(reader, replayer, chains, item.index, fresh=fresh)
            if short is not None:
                return short
        elif not missing and scene is not None and scene.short:  # (its scene's history was a last step too)
            return ReplayedHistory(short=True)
        return self._replay_missing(reader, replayer, chains, item, done)

    def _last_step(self, reader: EpisodeReader, replayer: EpisodeReplayer, chains: SceneChains,
                   index: int, *, fresh: bool) -> ReplayedHistory | None:
        """The history of episode `index` as the last step of the episode right before it (`step_before`), re-run on a
        rebuilt scene (unless `fresh`: one that ran nothing since it was built) from its recorded state before the
        episode's reset; None where that step cannot be had."""
        found = step_before(reader, chains, index, None)
        if found.run is None or found.run.episode is None:
            return None
        if not fresh:
            replayer.forget_scene()
        why = last_step_history(found.run.episode.index, chains.ran_before[index] or 0)
        return ReplayedHistory(before=found.run, steps=1, why=why, short=True)

    def _whole_history(self, reader: EpisodeReader, replayer: EpisodeReplayer, item: WorkItem,
                       why: str) -> ReplayedHistory:
        """Episode `item.index`'s whole history, replayed on a rebuilt scene (`why`: for its report)."""
        history = self._replay_missing(reader, replayer, self._chains_of(item.path, reader), item, None)
        return dataclasses.replace(history, why=history.lost or why)

    def _replay_missing(self, reader: EpisodeReader, replayer: EpisodeReplayer, chains: SceneChains, item: WorkItem,
                        done: int | None) -> ReplayedHistory:
        """Replay the predecessors of `item` from place `done` on (None: its whole history, on a rebuilt scene)."""
        missing = chains.history(item.index, since=done or 0)
        if done is None and not (missing or [reader.episode_meta(item.index)])[0].reconfigured:
            replayer.forget_scene()  # (a chain whose first reset rebuilt the scene rebuilds it itself)
        for ep in missing:
            try:
                replayer.replay_rows(reader.open_episode(ep.index), BlockSink(), mode="actions",
                                     rows=self.job.block_rows)
            except EPISODE_DATA_ERRORS as e:
                replayer.forget_scene()  # the episode itself then starts from a rebuilt scene, with no history
                return ReplayedHistory(lost=describe_unreadable_history(ep.index, e))
        if not missing:
            return ReplayedHistory()
        replayed = [ep.index for ep in missing]
        return ReplayedHistory(replayed, [ep.index for ep in chains.history(item.index)],
                               steps=sum(ep.length for ep in missing),
                               why=f"episode(s) {span(replayed)}, which its scene had not run")

    def _previous(self, reader: EpisodeReader, item: WorkItem) -> int:
        previous = self._chains_of(item.path, reader).previous(item.index)
        return previous.index if previous is not None else item.index - 1

    def _step_before(self, reader: EpisodeReader, replayer: EpisodeReplayer, item: WorkItem, scene: SceneRun | None,
                     *, shipped: bool) -> ReplayedHistory:
        """In a restoring mode, the step `item`'s recorder's scene ran before its reset, for the observations there
        (`simreel.replay.run.history.step_before`): none to re-run when no observation is replayed or the scene ran it last."""
        if not replayer.need_obs:
            return ReplayedHistory()
        if shipped:
            return ReplayedHistory(lost=describe_missing_step_before("sent without its file"))
        return restoring_history(reader, self._chains_of(item.path, reader), item, scene)

    def _chains_of(self, path: str, reader: EpisodeReader) -> SceneChains:
        """The chains of the file at `path` (`SceneChains`), found once per file the worker meets in a row."""
        if self._chains is None or self._chains[0] != path:
            self._chains = (path, SceneChains(reader.episodes))
        return self._chains[1]

    def prepare(self, item: WorkItem) -> None:
        """Open `item`'s file and build its env now; raises the `SimreelError` that stops that."""
        self._replayer_for(item, self._readers.get(item.path).meta)

    def _replayer_for(self, item: WorkItem, meta: RecordingMeta) -> EpisodeReplayer:
        key = item.key
        if key in self._failed:
            raise self._failed[key]
        if key != self._key or self._replayer is None:
            self._close_replayer()
            try:
                meta = self.job.meta_for(meta, item.path)
                self._replayer = EpisodeReplayer(meta, self.job.replayer_options(meta))
            except SimreelError as e:
                self._failed[key] = e
                raise
            self._key, self._scene = key, SceneRun()
        return self._replayer

    def _ran_in(self, item: WorkItem, reader: EpisodeReader, history: ReplayedHistory) -> ScenePlace | None:
        """For `-o`, where the replay of `item` ran (``provenance["scene"]`` of the replayed episode,
        `simreel.verdicts.scene_history`): in an actions replay after its recorded history, the recorded episode's scene;
        without it (a rebuilt scene), a chain of its own in the output. None: not written, or states restored."""
        if self.job.output is None or self.job.mode != "actions":
            return None
        if history.lost is not None:
            return ScenePlace(str(Path(self.job.output).resolve()), item.index, 0)
        chains = self._chains_of(item.path, reader)
        return chains.copied_scene(item.index, str(Path(item.path).resolve()), reader.meta.recording_id)

    def _replay(self, reader: EpisodeReader, replayer: EpisodeReplayer, index: int, history: ReplayedHistory,
                ran_in: ScenePlace | None = None) -> tuple[EpisodeReport, Episode | Path | None]:
        """Replay episode `index` block by block, comparing each block as it is replayed (and, for `-o`, writing it
        where `_stream` says); only the per-key error curves outlive a block. `history`: how its scene's history was
        replayed just before (`_replay_history`), which its report notes. Returns the report and, for `-o`, the scratch
        recording the replay went to, or (no scratch folder) the replay collected whole."""
        job = self.job
        source = reader.open_episode(index)
        scope = CompareScope(initial=source.meta.initial_state_known,
                             obs=job.obs_mode is None or job.obs_mode == reader.meta.obs_mode)
        stream = self._stream(reader.meta, source.meta, direct=not history.short)
        kept = Collected() if job.output is not None and stream is None else None
        written: BlockSink | None = stream or kept
        if written is not None and job.mode == "states":
            written = RecordedContacts(written)
        verify = VerifySink(job.tolerances, reader.meta.contact_channels, scope, written)
        verify.explain = not history.short
        try:
            replayer.rerun_step_before(history.before)
            replayed = replayer.replay_rows(source, verify, mode=job.mode, resync=job.resync, rows=job.block_rows)
            report = self._report(reader, replayer, source, replayed, verify)
            history.tell(report, index)
        except BaseException:
            if stream is not None:
                stream.discard()
            raise
        if history.short and report.verdict != "exact":  # `run` replays it again, after its whole history
            if stream is not None:
                stream.discard()
            return report, None
        if stream is not None:
            stream.commit(_replayed_meta(source.meta, report, ran_in), source.length)
        if kept is None:
            return report, stream.path if isinstance(stream, ScratchEpisode) else None
        episode = kept.episode(source.meta)
        return report, dataclasses.replace(episode, meta=_replayed_meta(episode.meta, report, ran_in))

    def _stream(self, meta: RecordingMeta, episode: EpisodeMeta, *, direct: bool = True) -> EpisodeStream | None:
        """Where the replay of `episode` (of the recording with `meta`) is written as it comes: into `-o` when this
        process writes it, the episode is next and the replay is no attempt that may be dropped (`direct`: an output
        never takes an episode index twice); else, given a scratch folder, into a scratch recording of its own; else
        nowhere (None: without `-o`, or collected whole)."""
        job = self.job
        stream = self.output.stream(episode) if self.output and direct else None
        if stream is None and job.output is not None and job.scratch is not None:
            spec = ReplayOutput(job.output, obs_mode=job.obs_mode, pose_bodies=output_pose_bodies(meta, job.output))
            stream = ScratchEpisode(Path(job.scratch), spec, meta, episode)
        return stream

    def _report(self, reader: EpisodeReader, replayer: EpisodeReplayer, source: EpisodeRows,
                replayed: ReplayedEpisode, verify: VerifySink) -> EpisodeReport:
        """The report of `source`'s replay, judged by `verify`, explained where it diverged (not when it is only an
        attempt after a short history, `ReplayedHistory.short`, which `run` replays again unless exact)."""
        meta = reader.meta
        cmp = verify.comparison()
        report = EpisodeReport.from_comparison(source, cmp, notes=replayed.notes, limits=replayed.limits,
                                               seconds=replayed.seconds)
        report.scene_differences = replayed.scene_differences
        if cmp.first_divergence is not None and verify.explain:  # after the report's timing: explaining steps again
            from simreel.replay.run.fingerprint import fingerprint_differences

            ctx = ExplainContext(mode=self.job.mode, resync=self.job.resync, channels=list(meta.contact_channels),
                                 env_id=meta.env_id, build_differences=fingerprint_differences(meta, replayer.u))
            # the recorded episode again, without its observations (camera frames), for the explanation's replays
            recorded = source.episode(obs=False)
            report.explanation = explain_divergence(replayer, recorded, replayed, cmp, ctx)
        return report

    def _warnings(self, path: str, reader: EpisodeReader, replayer: EpisodeReplayer) -> list[str]:
        """What to say once of the file `path`: what its reader noticed (e.g. groups a ManiSkill sidecar does not
        list, which are not replayed) and where its build differs from this machine's."""
        from simreel.replay.run.fingerprint import fingerprint_differences

        if path in self._warned:
            return []
        self._warned.add(path)
        return [*getattr(reader, "notes", []), *fingerprint_differences(reader.meta, replayer.u)]

    def _close_replayer(self) -> None:
        if self._replayer is not None:
            self._replayer.close()
            self._replayer, self._key, self._scene = None, None, None

    def close(self) -> None:
        self._close_replayer()
        self._readers.close()


def _replayed_meta(meta: EpisodeMeta, report: EpisodeReport, ran_in: ScenePlace | None) -> EpisodeMeta:
    """The metadata `-o` writes with a replayed episode: the recorded one's, with the replay's verdict and where the
    replay ran (`ReplayWorker._ran_in`)."""
    provenance = {**meta.provenance, "scene": ran_in.to_json()} if ran_in is not None else meta.provenance
    return dataclasses.replace(meta, verification=report.verification(), provenance=provenance)


_WORKER: Any = None
"""A worker process's worker, or the user error that building it raised (given back with each item)."""


def _worker_init(job: Any, parent: int, first: WorkItem | None = None) -> None:
    """Build this process's worker: ``job.open_worker()`` (a `ReplayJob`, or another picklable job, such as a
    conversion's), and where `first` is given, build its env now (`start_pool`): the error that stops it comes
    back with the item, as any other. `parent`: the pid of the process that started the pool (`start_pool` gives
    it): this process ends when that one is gone, even if it was gone before this one got here."""
    global _WORKER
    setup_worker_process(parent)
    try:
        _WORKER = job.open_worker()
        if first is not None and hasattr(_WORKER, "prepare"):
            _WORKER.prepare(first)
    except SimreelError as e:  # an initializer that raises breaks the whole pool (BrokenProcessPool)
        if _WORKER is None:
            _WORKER = e


def _ready() -> None:
    """Nothing: submitted to start a pool's processes before work is handed out (`start_pool`)."""


def _worker_run(item: WorkItem) -> EpisodeResult:
    if _WORKER is None:
        raise RuntimeError("_worker_run called in a process that _worker_init did not set up")
    if isinstance(_WORKER, SimreelError):
        return EpisodeResult(item, error=_WORKER)
    return _WORKER.run(item)


class Lanes:
    """A local pool: `workers - 1` worker processes, each behind an executor of its own (a lane), so that the items
    handed to one lane run in that process, in the order given. One shared pool would hand an actions replay's
    chain (`WorkItem.chain`) to every process, and each would replay the others' episodes again as history."""

    def __init__(self, executors: list[ProcessPoolExecutor]) -> None:
        self.executors = executors
        self.started: list[tuple[Any, Future]] = []
        """Each lane's process (a `multiprocessing.Process`) and the future of its first call (`_ready`), noted when
        `start_pool` starts them: what `death` reads once one has died."""

    def death(self) -> tuple[str, bool]:
        """How a dead worker process ended, in words for `WorkerDiedError`, and whether it may have run out of memory:
        killed by a signal (the OOM killer's, a kill -9) or unknown, or ended by an error of its own (its exit status;
        Python printed the error), which before it was ready is most often a script that starts a replay with workers
        outside a main guard: each worker process imports the script again (multiprocessing's "spawn")."""
        for process, ready in self.started:
            status = process.exitcode
            if status is not None and status < 0:
                return f"was killed by {_signal_name(-status)} (out of memory? a kill -9?)", True
            if status:
                if ready.done() and ready.exception() is None:
                    return f"ended with exit status {status} (its error is printed above)", False
                guard = ('; a script that starts a replay with workers must do so under `if __name__ == "__main__":`,'
                         " as each worker process imports the script again" if _main_is_a_script() else "")
                return f"ended with exit status {status} as it started (its error is printed above{guard})", False
        return "died (killed from outside: out of memory?)", True

    def stop(self) -> None:
        """End the processes now (Ctrl-C, an error raised here): an episode they are replaying is not waited for."""
        for executor in self.executors:
            for process in list((getattr(executor, "_processes", None) or {}).values()):
                process.terminate()

    def shutdown(self) -> None:
        for executor in self.executors:
            executor.shutdown(wait=True, cancel_futures=True)


def start_pool(job: Any, workers: int, first: WorkItem | None = None) -> Lanes:
    """`workers - 1` worker processes for `job`, started now: each imports, builds its worker and, given `first`,
    that item's env while this process prepares its own (a worker costs seconds to start, as long as tens of
    steps). Hand them to `run_pool`; `pool_closing` shuts them down."""
    ctx = spawn_context()
    lanes = Lanes([ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_worker_init,
                                       initargs=(job, os.getpid(), first)) for _ in range(workers - 1)])
    try:
        with launched():
            for executor in lanes.executors:
                ready = executor.submit(_ready)  # starts the lane's process now
                lanes.started += [(process, ready) for process in executor._processes.values()]
    except BaseException:  # Ctrl-C or SIGTERM, handled once the processes are started: they end with the pool
        lanes.stop()
        lanes.shutdown()
        raise
    return lanes


def run_pool(worker: Any, items: Iterable[WorkItem], workers: int, collect: Callable[[EpisodeResult], Any],
             pool: Lanes | None = None) -> None:
    """Replay `items` in `worker` (this process) and `workers - 1` worker processes (`pool`, from `start_pool`, or
    started here); `collect` each result here, as it arrives. Items of one chain (`WorkItem.chain`) are replayed by
    one process, in order. `worker` is a `ReplayWorker`, or another with ``job`` (whose ``open_worker()`` builds one
    in each process) and ``run(item) -> EpisodeResult``. When `collect` raises (a strict run meeting an error,
    Ctrl-C), the queued items are dropped and the pool is shut down — by whoever started it: here, or the caller
    that passed `pool`."""
    with pool_closing(start_pool(worker.job, workers)) if pool is None else contextlib.nullcontext(pool) as owned:
        _Feed(worker, owned, collect).run(deque(chain_groups(items)))


@contextlib.contextmanager
def pool_closing(pool: Lanes | None) -> Iterator[Lanes | None]:
    """Shut `pool` down when the block ends: at once (its processes ended, the episodes they were replaying not
    waited for) when the block raised, a strict run's error or Ctrl-C. None: no pool, nothing to do."""
    if pool is None:
        yield None
        return
    try:
        yield pool
    except BaseException:
        pool.stop()
        raise
    finally:
        pool.shutdown()


_AHEAD = 2
"""Items handed to a lane at a time: one replaying, one waiting, so its process never idles between two."""


class _Feed:
    """Hands groups of items (`simreel.replay.run.worklist.chain_groups`) to the lanes of a pool and to this process,
    one group to each at a time, and collects every result here. `WorkerDiedError` when a worker process dies
    (killed from outside) with the items the lanes then held."""

    def __init__(self, worker: Any, pool: Lanes, collect: Callable[[EpisodeResult], Any]) -> None:
        self.worker, self.pool, self.collect = worker, pool, collect
        self.lanes: list[tuple[ProcessPoolExecutor, deque[WorkItem]]] = [(e, deque()) for e in pool.executors]
        """Each lane's executor and the items of its group not yet handed to it."""
        self.pending: dict[Future, tuple[WorkItem, ProcessPoolExecutor]] = {}
        """Each item handed to a lane and not yet collected, with its lane."""
        self.here: deque[WorkItem] = deque()
        """The items of this process's group still to replay."""

    def run(self, groups: deque[list[WorkItem]]) -> None:
        try:
            while True:
                self._hand_out(groups)
                if self.here or groups:
                    self.collect(self.worker.run(next_item(self.here, groups)))
                    done = {fut for fut in self.pending if fut.done()}
                elif self.pending:
                    done, _ = wait(self.pending, return_when=FIRST_COMPLETED)
                else:
                    return
                for fut in done:
                    result = fut.result()
                    del self.pending[fut]
                    self.collect(result)
        except BrokenProcessPool:
            raise WorkerDiedError([item for item, _ in self.pending.values()], *self.pool.death()) from None

    def _hand_out(self, groups: deque[list[WorkItem]]) -> None:
        """Top up each lane to `_AHEAD` items in flight, from its group, then from the next group."""
        held = Counter(lane for _, lane in self.pending.values())
        for executor, left in self.lanes:
            while held[executor] < _AHEAD and (left or groups):
                item = next_item(left, groups)
                self.pending[executor.submit(_worker_run, item)] = (item, executor)
                held[executor] += 1


class WorkerDiedError(ReplayError):
    """A worker process of the pool died (`how`, `Lanes.death`: the OOM killer, a kill -9, an error of its own): the
    pool cannot go on, and the episodes it held (`lost`) have no result. The run stops rather than replaying them
    again: what killed the process (memory, most often: `memory`) would likely kill the next one too; the caller
    says how to finish the run."""

    def __init__(self, lost: list[WorkItem], how: str = "died", memory: bool = True) -> None:
        self.lost, self.how, self.memory = lost, how, memory
        shown = ", ".join(f"{Path(item.path).name}:{item.index}" for item in lost[:6])
        more = f" and {len(lost) - 6} more" if len(lost) > 6 else ""
        held = f"; the pool was replaying episode(s) {shown}{more}" if lost else ""
        super().__init__(f"a worker process {how}{held}")

    def __reduce__(self) -> tuple[type, tuple[list[WorkItem], str, bool]]:
        return type(self), (self.lost, self.how, self.memory)


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def _main_is_a_script() -> bool:
    """Whether this process runs a Python file as its main module (``python script.py``), which multiprocessing's
    "spawn" imports again in each worker process; not ``python -m simreel``, an interactive session or ``-c``."""
    import sys

    main = sys.modules.get("__main__")
    return bool(getattr(main, "__file__", None)) and getattr(getattr(main, "__spec__", None), "name", None) is None


def _first(report: EpisodeReport) -> str | None:
    """Where `report`'s replay first differed from its recording, in words (None: nowhere past its tolerance)."""
    return report.first_divergence.describe() if report.first_divergence is not None else None
