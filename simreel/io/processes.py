"""Worker processes that a command starts for its episodes (`simreel replay --workers`, `simreel export --workers`):
started with multiprocessing's ``spawn`` (sapien/torch state must not be forked) under `launched`, each set up by
`setup_worker_process` first thing: Ctrl-C is the parent's to handle (it stops them), each ends when its parent is
gone, and each runs torch/BLAS on one thread."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Iterator
from typing import Any

from simreel.io.durable import deferred_signals

__all__ = ["spawn_context", "launched", "setup_worker_process"]


def spawn_context() -> Any:
    """multiprocessing's ``spawn`` context: sapien/torch state must not be forked."""
    return multiprocessing.get_context("spawn")


@contextlib.contextmanager
def launched() -> Iterator[None]:
    """Start worker processes in the block with SIGINT and SIGTERM held here, and SIGINT blocked in the processes
    until `setup_worker_process` ignores it. A stop handled half way through a start left a process reading its set-up
    from a closed pipe, and a terminal's Ctrl-C (which reaches every process of the group) that found a process still
    importing before its set-up: each printed a traceback under the command's one line."""
    with deferred_signals():
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # inherited by the processes started now
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def setup_worker_process(parent: int) -> None:
    """Set up a worker process started under `launched`: SIGINT ignored (the parent stops the workers), this process
    ended once `parent` (the pid of the process that started it) is gone, one thread for torch and BLAS."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops the workers
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked since its start (`launched`)
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()
    _one_thread_per_process()


def _one_thread_per_process() -> None:
    """A pool of N processes on N cores: torch's intra-op threads (one per core in each process by default)
    would only compete with the other workers. Unless the user set it, one thread each."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _exit_with_parent(parent: int) -> None:
    """End this worker process when its parent `parent` is gone (killed with -9, it cannot stop its workers): a
    worker waiting for work does not notice by itself, and would wait on, orphaned. The pid comes from the parent,
    not from `os.getppid()` here: a parent killed while this process was still starting has already handed it to
    init (pid 1, or a subreaper), which would then pass for the parent forever."""
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)
