"""The shards of an export written in parallel (`write_shards`): `split_episodes` cuts the planned episodes into
consecutive runs of about equal frames, one a worker; the first is written in this process, the others each in a
worker process of its own (multiprocessing's ``spawn``: `simreel.io.processes`) or, with Ray, each as a Ray task,
every shard into a folder of its own (`shard_folder`). Results come back in the shards' order.

A worker that raises sends its error back, and it is raised here; Ctrl-C, SIGTERM or an error here stops the
workers (SIGTERM: each ends its ffmpeg processes first) and waits for them, so that no process is left writing once
the export's staging folder is removed. Ray tasks stopped with ``ray.cancel(force=True)`` leave ffmpeg its closed
input, on which it ends by itself."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from simreel.datasets.inputs import file_identity
from simreel.errors import SimreelError, Terminated, UsageError
from simreel.io.processes import launched, setup_worker_process, spawn_context
from simreel.training.lerobot.shard import ExportJob, PlannedEpisode, ShardResult, write_shard

__all__ = ["split_episodes", "shard_folder", "write_shards", "ExportWorkerError"]

_STOP_SECONDS = 10.0
"""How long a stopped worker process has to end its ffmpeg processes before it is killed."""

Progress = Callable[[int], Any] | None


class ExportWorkerError(SimreelError):
    """A worker process of an export died without a word (killed from outside: out of memory?, a kill -9)."""


def split_episodes(episodes: Sequence[PlannedEpisode], workers: int) -> list[list[PlannedEpisode]]:
    """`episodes` in at most `workers` consecutive runs, none empty, of about equal frames each."""
    total = max(1, sum(e.ref.length for e in episodes))
    count = max(1, min(workers, len(episodes)))
    shards: list[list[PlannedEpisode]] = [[] for _ in range(count)]
    done = shard = 0
    for number, episode in enumerate(episodes):
        middle = 2 * done + episode.ref.length  # twice the frames up to the episode's middle
        wanted = min(middle * count // (2 * total), shard + 1, count - 1)  # never past the next: none left empty
        shard = max(wanted, count - (len(episodes) - number))  # as many episodes left as shards: one each
        shards[shard].append(episode)
        done += episode.ref.length
    return shards


def shard_folder(folder: Path, number: int) -> Path:
    """Where shard `number` writes: the dataset folder itself for the first, a hidden folder in it for the others
    (their files take their numbers in the dataset when the export finishes)."""
    return folder if number == 0 else folder / f".shard-{number:03d}"


def write_shards(job: ExportJob, shards: Sequence[Sequence[PlannedEpisode]], folder: Path, *, ray: str | None = None,
                 progress: Progress = None) -> list[ShardResult]:
    """Write each shard into its `shard_folder` of `folder`: the first here and the others in worker processes, or
    all as Ray tasks on the cluster `ray` ("local", "auto" or an address); `progress` is called here with each
    episode's frames once written (with Ray, with each shard's once it is done)."""
    if ray is not None:
        return _on_ray(job, shards, folder, ray, progress)
    if len(shards) == 1:
        return [write_shard(job, shards[0], folder, progress)]
    return _in_processes(job, shards, folder, progress)


# ---------------------------------------------------------------------------------------------- worker processes
def _in_processes(job: ExportJob, shards: Sequence[Sequence[PlannedEpisode]], folder: Path,
                  progress: Progress) -> list[ShardResult]:
    context = spawn_context()
    workers: list[tuple[Any, Connection]] = []
    try:
        with launched():
            for number, shard in enumerate(shards[1:], start=1):
                here, there = context.Pipe(duplex=False)
                process = context.Process(target=_shard_process, daemon=True,
                                          args=(job, list(shard), shard_folder(folder, number), there, os.getpid()))
                process.start()
                there.close()
                workers.append((process, here))
        results: dict[int, ShardResult] = {}

        def progress_here(frames: int) -> None:
            if progress is not None:
                progress(frames)
            _collect(workers, results, progress, timeout=0)  # a worker's error stops the export now

        first = write_shard(job, shards[0], folder, progress_here)
        while len(results) < len(workers):
            _collect(workers, results, progress, timeout=None)
        return [first, *(results[n] for n in range(len(workers)))]
    except BaseException:
        _stop(workers)
        raise
    finally:
        for process, conn in workers:
            process.join()
            conn.close()


def _collect(workers: list[tuple[Any, Connection]], results: dict[int, ShardResult], progress: Progress, *,
             timeout: float | None) -> None:
    """Read what the workers have sent (waiting up to `timeout` for something, None: until something comes):
    progress, a shard's result (into `results`, by worker number), or an error, raised here."""
    open_ = {conn: n for n, (_, conn) in enumerate(workers) if n not in results}
    for conn in wait(list(open_), timeout=timeout):
        number = open_[conn]
        while number not in results and conn.poll():
            try:
                kind, value = conn.recv()
            except EOFError:
                raise ExportWorkerError(f"an export worker process {_how_it_ended(workers[number][0])}; nothing "
                                        "was written") from None
            if kind == "frames":
                if progress is not None:
                    progress(value)
            elif kind == "done":
                results[number] = value
            else:
                raise value


def _how_it_ended(process: Any) -> str:
    """How a worker process that hung up without a word ended, in words."""
    process.join(_STOP_SECONDS)  # (it may not be reaped yet)
    code = process.exitcode
    if code is not None and code < 0:
        return f"was killed by {signal.Signals(-code).name} (out of memory? a kill -9?)"
    return f"ended with exit status {code} (its error is printed above)" if code else "died"


def _stop(workers: list[tuple[Any, Connection]]) -> None:
    """End the worker processes: SIGTERM (each ends its ffmpeg processes), then SIGKILL for one that lingers."""
    for process, _ in workers:
        if process.is_alive():
            process.terminate()
    for process, _ in workers:
        process.join(_STOP_SECONDS)
        if process.is_alive():
            process.kill()


def _terminated(signum: int, frame: Any) -> None:
    raise Terminated()


def _shard_process(job: ExportJob, shard: list[PlannedEpisode], folder: Path, conn: Connection, parent: int) -> None:
    """A worker process: write `shard`, sending each episode's frame count, then ("done", result) or ("error", the
    error) through `conn`. SIGTERM (the parent stopping it) ends it, its ffmpeg processes first."""
    setup_worker_process(parent)
    signal.signal(signal.SIGTERM, _terminated)
    try:
        result = write_shard(job, shard, folder, lambda frames: conn.send(("frames", frames)))
        answer = ("done", result)
    except Terminated:
        return
    except BaseException as e:  # noqa: BLE001 - every error goes back to the parent, which raises it
        answer = ("error", _sendable(e))
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # its work is done: a stop now just ends it, quietly
    conn.send(answer)


def _sendable(error: BaseException) -> BaseException:
    """`error`, or where it cannot be pickled whole, a `RuntimeError` that says the same."""
    import pickle

    try:
        pickle.loads(pickle.dumps(error))
        return error
    except Exception:  # noqa: BLE001 - any error of pickling
        return RuntimeError(f"{type(error).__name__}: {error}")


# ---------------------------------------------------------------------------------------------------------- Ray
def _on_ray(job: ExportJob, shards: Sequence[Sequence[PlannedEpisode]], folder: Path, address: str,
            progress: Progress) -> list[ShardResult]:
    from simreel.io.ray_cluster import connect, import_ray

    ray = import_ray()
    connect(ray, address)
    refs: list[Any] = []
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_shard)
        inputs = sorted({(e.ref.path, *file_identity(e.ref.path)) for shard in shards for e in shard})
        refs = [task.remote(job, list(shard), str(shard_folder(folder, n)), str(folder), inputs)
                for n, shard in enumerate(shards)]
        frames = {ref: sum(e.ref.length for e in shard) for ref, shard in zip(refs, shards, strict=True)}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            _ray_result(ray, done[0])
            if progress is not None:
                progress(frames[done[0]])
        return ray.get(refs)
    except BaseException:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise
    finally:
        ray.shutdown()


def _ray_result(ray: Any, ref: Any) -> ShardResult:
    """The result of a finished task, or its error raised here: a simreel error as itself (one line), another as a
    `RuntimeError` naming it (Ray's own wraps it in the task's traceback)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as e:
        cause = e.cause
        if isinstance(cause, SimreelError):
            raise cause from None
        raise RuntimeError(f"a Ray task of the export failed: {type(cause).__name__}: {cause}") from None


def _ray_shard(job: ExportJob, shard: list[PlannedEpisode], target: str, folder: str,
               inputs: list[tuple[str, int | None, int | None]]) -> ShardResult:
    """A Ray task: write `shard` into `target`, where this node sees the export's folder and its recordings as the
    driver does (a shared filesystem)."""
    import socket

    unseen = [path for path, size, mtime_ns in inputs if _identity(path) != (size, mtime_ns)]
    if not Path(folder).is_dir() or unseen:
        what = f"the recording {unseen[0]}" if unseen else f"the export's folder {folder}"
        raise UsageError(f"--ray: the Ray worker on {socket.gethostname()} does not see {what} as this machine does; "
                         "export with --ray onto a filesystem the cluster shares, and from recordings on it")
    Path(target).mkdir(parents=True, exist_ok=True)
    return write_shard(job, shard, Path(target))


def _identity(path: str) -> tuple[int | None, int | None] | None:
    try:
        return file_identity(path)
    except OSError:
        return None
