"""Replay a work list on a Ray cluster (`simreel replay --ray`): `run_ray`.

Each of `workers` Ray actors holds a `ReplayWorker` — its env built once per env key, kept across episodes — and
replays the work items the driver hands it, a few at a time. An actor reads each recording where it is when
it sees the same file (path, size and modification time: a shared filesystem); otherwise, or always with
``ship=True``, the driver reads the episode and sends it. An actor that dies (its process killed, its node
lost) is replaced and its unfinished episodes go to the others; an episode whose actor died `MAX_ATTEMPTS`
times is reported as an error rather than retried for ever. Each episode's result reaches `collect` once.

Ray is an optional dependency (``pip install 'simreel[ray]'``); it is imported only here.
"""

from __future__ import annotations

import logging
import os
import socket
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from simreel.episode import Episode, RecordingMeta
from simreel.errors import RecordingFileError, UsageError
from simreel.formats import EpisodeReader
from simreel.formats.base import EpisodeRows
from simreel.formats.inputs import file_identity
from simreel.replay.workers import EpisodeResult, ReaderCache, ReplayJob, ReplayWorker
from simreel.replay.worklist import RecordingInfo, WorkItem

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
        raise UsageError("--ray needs Ray: pip install 'simreel[ray]' (make setup installs it)") from None
    return ray


def _connect(ray: Any, address: str) -> None:
    """Join or start the cluster; `UsageError` naming the address when there is none."""
    quiet = {"logging_level": logging.ERROR, "log_to_driver": False, "include_dashboard": False}
    try:
        if address == "local":
            ray.init(object_store_memory=_OBJECT_STORE_BYTES, **quiet)
        else:
            ray.init(address=address, **quiet)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise UsageError(f"--ray {address}: no Ray cluster to join there ({type(e).__name__}: {e}); start one "
                         "(ray start --head) or give its address (host:6379, ray://host:10001)") from None


class _Fleet:
    """The actors of a run and the episodes each is replaying."""

    def __init__(self, ray: Any, job: ReplayJob, options: RayOptions, files: list[RecordingInfo]) -> None:
        self.ray, self.job, self.options = ray, job, options
        self.files = {f.path: f for f in files}
        self.remote = ray.remote(num_cpus=1, max_restarts=0)(_Actor)
        self.actors: list[Any] = []
        self.sees: dict[Any, set[str]] = {}
        self.where: dict[Any, str] = {}
        self.inflight: dict[Any, tuple[Any, WorkItem, bool]] = {}
        """Result ref → (actor, item, whether the driver sent the episode)."""
        self.attempts: dict[tuple[str, int], int] = {}
        self.deaths = 0
        self.replayed_again = 0
        self._readers = ReaderCache()
        self._start_actors(options.workers)

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
        queue = deque(items)
        while queue or self.inflight:
            self._hand_out(queue)
            done, _ = self.ray.wait(list(self.inflight), num_returns=1)
            for ref in done:
                actor, item, shipped = self.inflight.pop(ref)
                try:
                    result = self.ray.get(ref)
                except self.ray.exceptions.RayActorError:
                    self._lost(actor, item, queue, collect)
                    continue
                result.worker = self.where[actor] + (" (episode sent by the driver)" if shipped else "")
                collect(result)

    def _hand_out(self, queue: deque[WorkItem]) -> None:
        for actor in self.actors:
            busy = sum(1 for a, *_ in self.inflight.values() if a is actor)
            while queue and busy < _AHEAD:
                item = queue.popleft()
                key = (item.path, item.index)
                self.attempts[key] = self.attempts.get(key, 0) + 1
                shipped = None if item.path in self.sees[actor] else self._ship(item)
                self.inflight[actor.run.remote(item, shipped)] = (actor, item, shipped is not None)
                busy += 1

    def _ship(self, item: WorkItem) -> ShippedEpisode:
        reader = self._readers.get(item.path)
        return ShippedEpisode(item.path, reader.meta, reader.read_episode(item.index))

    def _lost(self, actor: Any, item: WorkItem, queue: deque[WorkItem], collect: Callable[[EpisodeResult], Any]) -> None:
        """`item`'s actor died: replace the actor once, and hand the item out again or report it."""
        if actor in self.actors:
            self.actors.remove(actor)
            self.deaths += 1
            self._start_actors(1)
        if self.attempts[(item.path, item.index)] >= MAX_ATTEMPTS:
            error = RecordingFileError(item.path, f"episode {item.index}: the Ray worker replaying it died "
                                                  f"{MAX_ATTEMPTS} times (see the Ray logs of its node)")
            collect(EpisodeResult(item, error=error))
        else:
            self.replayed_again += 1
            queue.appendleft(item)

    def close(self) -> None:
        for actor in self.actors:
            self.ray.kill(actor)
        self._readers.close()


def run_ray(job: ReplayJob, items: list[WorkItem], options: RayOptions, files: list[RecordingInfo],
            collect: Callable[[EpisodeResult], Any]) -> list[str]:
    """Replay `items` (episodes of `files`) on Ray actors, calling `collect` here with each result as it comes;
    returns notes on what happened on the way (workers that died)."""
    ray = _import_ray()
    _connect(ray, options.address)
    fleet = None
    try:
        fleet = _Fleet(ray, job, options, files)
        fleet.run(items, collect)
    finally:
        if fleet is not None:
            fleet.close()
        ray.shutdown()
    if not fleet.deaths:
        return []
    return [f"{fleet.deaths} Ray worker(s) died during the run; the {fleet.replayed_again} episode(s) they were "
            "replaying were replayed again by others (each counted once)"]
