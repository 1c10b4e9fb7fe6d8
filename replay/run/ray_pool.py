"""Replay a work list on a Ray cluster (`simreel replay --ray`): `run_ray`.

Each of `workers` Ray actors (at most one per CPU of the cluster: each takes one) holds a `ReplayWorker` — its
env built once per env key, kept across episodes — and replays the work items the driver hands it, a few at a
time. An actor reads each recording where it is when
it sees the same file (path, size and modification time: a shared filesystem); otherwise, or always with
``ship=True``, the driver reads the episode and sends it. An actor that dies (its process killed, its node
lost) is replaced and its unfinished episodes go to the others; an episode whose actor died `MAX_ATTEMPTS`
times is reported as an error rather than retried for ever. Each episode's result reaches `collect` once.

Ray is an optional dependency (``pip install 'simreel[ray]'``), imported only when a run asks for it
(`simreel.io.ray_cluster`).
"""

from __future__ import annotations

import contextlib
import os
import socket
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from simreel.datasets.inputs import file_identity
from simreel.errors import RecordingFileError
from simreel.formats import EpisodeReader
from simreel.formats.base import EpisodeRows
from simreel.io.ray_cluster import connect, import_ray, worker_count
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
    ray = import_ray()
    connect(ray, options.address)
    fleet = None
    try:
        actors, notes = worker_count(ray, options.workers, did="replayed")
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
