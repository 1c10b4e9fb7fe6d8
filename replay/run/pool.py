"""The local process pool of a run (`start_pool`, `run_pool`, `pool_closing`): worker processes started with
``spawn`` (sapien/torch state must not be forked), one lane each (`Lanes`), so that the items of a chain run in one
process, in order; each process builds its own worker from the job (``job.open_worker()``) and ends with the
process that started it. `WorkerDiedError` when one dies."""

from __future__ import annotations

import contextlib
import os
import signal
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from simreel.errors import ReplayError, SimreelError
from simreel.io.processes import launched, setup_worker_process, spawn_context
from simreel.replay.run.job import EpisodeResult
from simreel.replay.run.worklist import WorkItem, chain_groups, next_item

__all__ = ["Lanes", "WorkerDiedError", "pool_closing", "run_pool", "start_pool"]


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
