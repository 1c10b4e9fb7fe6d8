"""Replay a work list on a Ray cluster (`simreel replay --ray`): `run_ray`.

Each of `workers` Ray actors (at most one per CPU of the cluster: each takes one) holds a `ReplayWorker` — its
env built once per env key, kept across episodes — and replays the work items the driver hands it, a few at a
time. An actor reads each recording where it is when
it sees the same file (path, size and modification time: a shared filesystem); otherwise, or always with
``ship=True``, the driver reads the episode and sends it. An actor that dies (its process killed, its node
lost) is replaced and its unfinished episodes go to the others; an episode whose actor died `MAX_ATTEMPTS`
times is reported as an error rather than retried for ever. Each episode's result reaches `collect` once.

Ray is an optional dependency (``pip install 'simreel[ray]'``); it is imported only here.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from simreel.datasets.inputs import file_identity
from simreel.errors import RecordingFileError, UsageError
from simreel.formats import EpisodeReader
from simreel.formats.base import EpisodeRows
from simreel.model.episode import Episode
from simreel.model.meta import RecordingMeta
from simreel.replay.run.job import EpisodeResult, ReplayJob
from simreel.replay.run.readers import ReaderCache
from simreel.replay.run.workers import ReplayWorker
from simreel.replay.run.worklist import RecordingInfo, WorkItem, chain_groups, next_item

__all__ = ["run_ray", "RayOptions", "ShippedEpisode", "MAX_ATTEMPTS"]

MAX_ATTEMPTS = 3
"""Times an episode is handed out before the deaths of the actors replaying it make it an error."""
_AHEAD = 2
"""Episodes in flight per actor: one replaying, one waiting, so an actor never idles on the driver."""
_OBJECT_STORE_BYTES = 256 * 1024**2
"""Object store of a cluster started here: enough for shipped episodes, small beside the envs."""


@dataclass(frozen=True)
class RayOptions:
    """Where and how `run_ray` runs: the cluster (`address`: "local" starts one here, "auto" joins this machine's,
    else a Ray address), the number of actors, and whether the driver always sends the episodes."""

    address: str = "local"
    workers: int = 1
    ship: bool = False


class ShippedEpisode(EpisodeReader):
    """One episode sent by the driver, read like a recording by an actor that cannot see the file."""

    def __init__(self, path: str, meta: RecordingMeta, episode: Episode) -> None:
        self.path = path  # type: ignore[assignment]
        self.meta = meta
        self.episodes = [episode.meta]
        self.kind = "episode shipped by the driver"
        self._episode = episode

    def open_episode(self, index: int) -> EpisodeRows:
        self.episode_meta(index)
        return EpisodeRows.of(self._episode)


class _Actor:
    """The Ray actor: a `ReplayWorker` and what it can see."""

    def __init__(self, job: ReplayJob) -> None:
        self.worker = ReplayWorker(job)

    def where(self) -> str:
        import ray

        return f"{socket.gethostname()} node {ray.get_runtime_context().get_node_id()[:8]} pid {os.getpid()}"

    def visible(self, files: list[tuple[str, int | None, int | None]]) -> list[str]:
        """The files this actor sees as the driver does: same path, size and modification time."""
        seen = []
        for path, size, mtime_ns in files:
            try:
                if file_identity(path) == (size, mtime_ns):
                    seen.append(path)
            except OSError:
                continue
        return seen

    def run(self, item: WorkItem, shipped: ShippedEpisode | None = None) -> EpisodeResult:
        return self.worker.run(item, shipped)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise UsageError("--ray needs Ray: pip install 'simreel[ray]' (in simreel's repository: "
                         ".venv/bin/pip install -e '.[ray]')") from None
    return ray


def _connect(ray: Any, address: str) -> None:
    """Join or start the cluster; `UsageError` naming the address when there is none. simreel's own SIGINT and
    SIGTERM handlers stay in place (`ray.init` installs its own, which would end a run with Ray's dumps and exit
    15 instead of the report's resume hint)."""
    quiet = {"logging_level": logging.ERROR, "log_to_driver": False, "include_dashboard": False}
    if address != "local":
        _check_reachable(address)
    with _signal_handlers_kept():
        try:
            if address == "local":
                # "local": a private instance, also where `ray start` runs a cluster (plain init would join it)
                ray.init(address="local", object_store_memory=_OBJECT_STORE_BYTES, **quiet)
            else:
                ray.init(address=address, **quiet)
        except (ConnectionError, RuntimeError, ValueError) as e:
            if address == "local":
                raise UsageError(f"--ray: cannot start Ray on this machine ({type(e).__name__}: {e}); join a "
                                 "running cluster instead (--ray auto, or its address)") from None
            raise UsageError(f"--ray {address}: no Ray cluster to join there ({type(e).__name__}: {e}); start one "
                             "(ray start --head) or give its address (host:6379, ray://host:10001)") from None


_CONNECT_SECONDS = 5.0
"""How long `_check_reachable` waits for a cluster's port to answer (Ray itself would retry for ever)."""


def _check_reachable(address: str) -> None:
    """`UsageError` when nothing listens at a ``host:port`` or ``ray://host:port`` address: `ray.init` retries such
    an address for ever. "auto" is Ray's to find (it fails at once when this machine belongs to no cluster)."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if address == "auto" or not sep or not port.isdigit():
        return
    host = host.strip("[]")  # an IPv6 address in brackets
    try:
        socket.create_connection((host, int(port)), timeout=_CONNECT_SECONDS).close()
    except OSError as e:
        why = "no answer" if isinstance(e, TimeoutError) else (e.strerror or str(e))
        raise UsageError(f"--ray {address}: no Ray cluster answers there ({why}); start one (ray start --head) or "
                         "give its address (host:6379, ray://host:10001)") from None


@contextlib.contextmanager
def _signal_handlers_kept() -> Iterator[None]:
    """Put simreel's SIGINT and SIGTERM handlers back after the block (`ray.init` replaces them: its SIGTERM one
    exits 15, and its core worker prints a stack dump), so a stopped run ends as a local one does. Only the main
    thread sets handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    kept = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in kept.items():
            if handler is not None:
                signal.signal(s, handler)  # also takes the signal back from Ray's C++ handler


def _actor_count(ray: Any, workers: int) -> tuple[int, list[str]]:
    """How many actors to start for `workers` (each takes one CPU) and the note that says so when the cluster has
    fewer CPUs: Ray would wait for ever to place the others. `UsageError` for a cluster without CPUs."""
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if cpus < 1:
        raise UsageError("--ray: the Ray cluster has no CPU for a worker (each takes one); add a node with CPUs")
    if workers <= cpus:
        return workers, []
    return cpus, [f"--workers {workers}: the Ray cluster has {cpus} CPU(s), one per worker, so {cpus} worker(s) "
                  "replayed"]


class _Fleet:
    """The actors of a run and the episodes each is replaying."""

    def __init__(self, ray: Any, job: ReplayJob, options: RayOptions, files: list[RecordingInfo],
                 actors: int) -> None:
        self.ray, self.job, self.options = ray, job, options
        self.files = {f.path: f for f in files}
        self.remote = ray.remote(num_cpus=1, max_restarts=0)(_Actor)
        self.actors: list[Any] = []
        self.sees: dict[Any, set[str]] = {}
        self.where: dict[Any, str] = {}
        self.inflight: dict[Any, tuple[Any, WorkItem, bool]] = {}
        """Result ref → (actor, item, whether the driver sent the episode)."""
        self.attempts: dict[tuple[str, int], int] = {}
        self.left: dict[Any, deque[WorkItem]] = {}
        """Per actor, the items of its group (`chain_groups`) not yet handed to it."""
        self.deaths = 0
        self.replayed_again = 0
        self._readers = ReaderCache()
        self._start_actors(actors)

    def _start_actors(self, n: int) -> None:
        """`n` more actors, started at once (each takes seconds to start), and what each of them sees."""
        started = [self.remote.remote(self.job) for _ in range(n)]
        identity = [(f.path, f.size, f.mtime_ns) for f in self.files.values()]
        answers = self.ray.get([ref for a in started for ref in (a.visible.remote(identity), a.where.remote())])
        for actor, seen, where in zip(started, answers[::2], answers[1::2], strict=True):
            self.sees[actor] = set() if self.options.ship else set(seen)
            self.where[actor] = where
            self.actors.append(actor)

    def run(self, items: Iterable[WorkItem], collect: Callable[[EpisodeResult], Any]) -> None:
        queue = deque(chain_groups(items))
        while queue or self.inflight:
            self._hand_out(queue)
            done, _ = self.ray.wait(list(self.inflight), num_returns=1)
            for ref in done:
                actor = self.inflight[ref][0]
                if not self._collected(ref, collect):
                    self._lost(actor, queue, collect)

    def _collected(self, ref: Any, collect: Callable[[EpisodeResult], Any]) -> bool:
        """Collect the result of `ref` (done); False, leaving it in flight, when its actor died first."""
        actor, _, shipped = self.inflight[ref]
        try:
            result = self.ray.get(ref)
        except self.ray.exceptions.RayActorError:
            return False
        del self.inflight[ref]
        result.worker = self.where[actor] + (" (episode sent by the driver)" if shipped else "")
        collect(result)
        return True

    def _hand_out(self, queue: deque[list[WorkItem]]) -> None:
        """Top up each actor to `_AHEAD` episodes in flight from its group of items (`chain_groups`: the episodes of
        one scene chain go to one actor, in order), then from the next group in `queue`."""
        for actor in self.actors:
            busy = sum(1 for a, *_ in self.inflight.values() if a is actor)
            left = self.left.setdefault(actor, deque())
            while (left or queue) and busy < _AHEAD:
                item = next_item(left, queue)
                key = (item.path, item.index)
                self.attempts[key] = self.attempts.get(key, 0) + 1
                shipped = None if item.path in self.sees[actor] else self._ship(item)
                self.inflight[actor.run.remote(item, shipped)] = (actor, item, shipped is not None)
                busy += 1

    def _ship(self, item: WorkItem) -> ShippedEpisode:
        reader = self._readers.get(item.path)
        return ShippedEpisode(item.path, reader.meta, reader.read_episode(item.index))

    def _lost(self, actor: Any, queue: deque[list[WorkItem]], collect: Callable[[EpisodeResult], Any]) -> None:
        """`actor` died: replace it, and hand out again, as one group in the order they were handed to it, the
        episodes it was replaying (those it died on too often reported instead) and the rest of its group, so that
        one actor replays that chain on (its history replayed once, not once per episode in flight)."""
        self.actors.remove(actor)
        self.deaths += 1
        with contextlib.suppress(Exception):  # (an actor Ray calls unavailable may still live, holding its CPU)
            self.ray.kill(actor)
        refs = [ref for ref, (a, *_) in self.inflight.items() if a is actor]  # (in the order handed out)
        done = set(self.ray.wait(refs, num_returns=len(refs), timeout=0)[0])
        again = []
        for ref in refs:
            if ref in done and self._collected(ref, collect):  # it finished before the actor died
                continue
            lost = self.inflight.pop(ref)[1]
            if self.attempts[(lost.path, lost.index)] >= MAX_ATTEMPTS:
                error = RecordingFileError(lost.path, f"episode {lost.index}: the Ray worker replaying it died "
                                                      f"{MAX_ATTEMPTS} times (see the Ray logs of its node)")
                collect(EpisodeResult(lost, error=error))
            else:
                again.append(lost)
        self.replayed_again += len(again)
        group = again + list(self.left.pop(actor, ()))
        if group:
            queue.appendleft(group)
        self._start_actors(1)

    def close(self) -> None:
        for actor in self.actors:
            self.ray.kill(actor)
        self._readers.close()


def run_ray(job: ReplayJob, items: list[WorkItem], options: RayOptions, files: list[RecordingInfo],
            collect: Callable[[EpisodeResult], Any]) -> list[str]:
    """Replay `items` (episodes of `files`) on Ray actors, calling `collect` here with each result as it comes;
    returns notes on what happened on the way (fewer workers than asked, workers that died)."""
    ray = _import_ray()
    _connect(ray, options.address)
    fleet = None
    try:
        actors, notes = _actor_count(ray, options.workers)
        fleet = _Fleet(ray, job, options, files, actors)
        fleet.run(items, collect)
    finally:
        if fleet is not None:
            fleet.close()
        ray.shutdown()
    if fleet.deaths:
        notes.append(f"{fleet.deaths} Ray worker(s) died during the run; the {fleet.replayed_again} episode(s) they "
                     "were replaying were replayed again by others (each counted once)")
    return notes
