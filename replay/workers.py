"""Where episodes are replayed: a `ReplaySession` (one reader, one rebuilt env) in this process, and one in
each worker process of a pool (`run_pool`), each replaying whole episodes and answering with their reports.

A `ReplayJob` is everything a session needs, picklable so that worker processes (started with ``spawn``:
sapien/torch state must not be forked) can build their own.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any

from simreel.compare import CompareScope, Tolerances, compare_episode
from simreel.episode import Episode
from simreel.errors import SimreelError
from simreel.formats import EpisodeReader, open_reader
from simreel.replay.engine import EpisodeReplayer, ReplayedEpisode, ReplayerOptions
from simreel.replay.report import EpisodeReport
from simreel.sim.user_code import resolve_task_imports

__all__ = ["ReplayJob", "ReplaySession", "EpisodeResult", "run_pool"]

EpisodeResult = tuple[EpisodeReport, Episode | None]
"""An episode's report, and its replayed arrays when they are written out (`-o`)."""


@dataclass(frozen=True)
class ReplayJob:
    """What every session of one run does: which file, which mode and tolerances, what env options."""

    path: str
    mode: str
    resync: int | None
    tolerances: Tolerances
    replayer: ReplayerOptions
    keep_episode: bool
    imports: tuple[str, ...] = ()
    """`--import` specs given now: used instead of the recorded ones (`resolve_task_imports`)."""


class ReplaySession:
    """One reader + one replayer; lives in the main process and in each worker process.

    `reader`: an open reader of `job.path` to use (and close with the session); None opens one.
    """

    def __init__(self, job: ReplayJob, reader: EpisodeReader | None = None) -> None:
        from simreel.replay.fingerprint import fingerprint_differences

        self.job = job
        self.reader = reader if reader is not None else open_reader(job.path)
        try:
            meta = self.reader.meta  # its task's code: the --import given now, else the recorded one, found here
            meta = dataclasses.replace(meta, imports=resolve_task_imports(meta.imports, explicit=job.imports,
                                                                          recording=job.path))
            self.meta = meta
            self.replayer = EpisodeReplayer(meta, job.replayer)
        except BaseException:
            self.reader.close()
            raise
        self.warnings = fingerprint_differences(meta, self.replayer.u)

    def run(self, index: int) -> EpisodeResult:
        recorded = self.reader.read_episode(index)
        replayed = self.replayer.replay(recorded, mode=self.job.mode, resync=self.job.resync)
        report = self._report(recorded, replayed)
        if not self.job.keep_episode:
            return report, None
        episode = replayed.episode
        if self.job.mode == "states":
            # states were restored from the recording; its contact forces are the true ones of the original run
            # (the replay's come from one step simulated from each restored state)
            episode = dataclasses.replace(episode, contact_forces=recorded.contact_forces)
        return report, episode

    def _report(self, recorded: Episode, replayed: ReplayedEpisode) -> EpisodeReport:
        obs_mode = self.job.replayer.obs_mode
        scope = CompareScope(initial=recorded.meta.initial_state_known,
                             obs=obs_mode is None or obs_mode == self.meta.obs_mode,
                             contacts=replayed.compare_contacts)
        cmp = compare_episode(recorded, replayed.episode, self.job.tolerances,
                              channels=self.meta.contact_channels, scope=scope)
        return EpisodeReport.from_comparison(recorded, cmp, notes=replayed.notes, limits=replayed.limits,
                                             seconds=replayed.seconds)

    def close(self) -> None:
        self.replayer.close()
        self.reader.close()


_WORKER: ReplaySession | SimreelError | None = None
"""A worker process's session, or the user error that building it raised (re-raised in the parent)."""


def _worker_init(job: ReplayJob) -> None:
    global _WORKER
    try:
        _WORKER = ReplaySession(job)
    except SimreelError as e:  # an initializer that raises breaks the whole pool (BrokenProcessPool)
        _WORKER = e


def _worker_run(index: int) -> EpisodeResult | SimreelError:
    """One episode's result, or the user error that stopped it (raised by the parent)."""
    if isinstance(_WORKER, SimreelError):
        return _WORKER
    if _WORKER is None:
        raise RuntimeError("_worker_run called in a process that _worker_init did not set up")
    try:
        return _WORKER.run(index)
    except SimreelError as e:
        return e


def _unwrap(result: EpisodeResult | SimreelError) -> EpisodeResult:
    if isinstance(result, SimreelError):
        raise result
    return result


def run_pool(session: ReplaySession, indices: Iterable[int], workers: int, collect: Callable[[EpisodeResult], Any]) -> None:
    """Replay `indices` in `session` (this process) and `workers - 1` worker processes; `collect` each result.

    The caller builds `session` first, so a user error (an --import that fails, an env that does not build,
    another state layout) is raised here before any worker starts; a worker returns the errors it meets
    instead of raising them, and they are raised here too. On an error, the queued episodes are dropped.
    """
    queue = deque(indices)
    ahead = 2 * (workers - 1)  # episodes handed to the workers at a time; the rest stay for this process
    ctx = multiprocessing.get_context("spawn")  # sapien/torch state must not be forked
    pool = ProcessPoolExecutor(max_workers=workers - 1, mp_context=ctx, initializer=_worker_init,
                               initargs=(session.job,))
    pending: set[Any] = set()
    try:
        while queue or pending:
            while queue and len(pending) < ahead:
                pending.add(pool.submit(_worker_run, queue.popleft()))
            if queue:
                collect(_unwrap(session.run(queue.popleft())))
                done = {fut for fut in pending if fut.done()}
            else:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
            pending -= done
            for fut in done:
                collect(_unwrap(fut.result()))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

