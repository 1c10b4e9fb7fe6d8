"""Replay a recording and verify every episode: the reports, and the loop behind `simreel replay`.

`verify_recording(path, mode=..., ...)` replays the chosen episodes (in this process, or with ``workers=N``
in this one and N - 1 worker processes, each with its own env), compares each with its recording
(`simreel.compare`) and returns a `ReplayReport`: one `EpisodeReport` per episode with its verdict (``exact``, ``within_tolerance`` or
``diverged``), the first divergence (step, key path, error, tolerance) and the largest error per key.
With ``output`` it also writes the replayed episodes as a simreel recording.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simreel.compare import Divergence, Tolerances, compare_episode, format_number, json_number, worst_keys
from simreel.episode import Episode, RecordingMeta
from simreel.errors import SimreelError, UsageError
from simreel.formats import format_of, open_reader
from simreel.replay.engine import MODES, EpisodeReplayer
from simreel.state_tree import layout_of

__all__ = ["EpisodeReport", "ReplayReport", "verify_recording"]


@dataclass
class EpisodeReport:
    """The verdict on one episode's replay."""

    index: int
    seed: int | None
    length: int
    verdict: str
    first_divergence: Divergence | None
    max_abs_error: dict[str, float]
    tolerance: dict[str, float] = field(default_factory=dict)
    diverged_keys: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    """How the replay was done, and what it could not check or reproduce (those also in `limits`)."""
    seconds: float = 0.0
    limits: list[str] = field(default_factory=list)
    """Notes on what was not checked or not reproduced ("contacts not compared: ..."): shown whatever the verdict."""

    @property
    def ok(self) -> bool:
        return self.verdict != "diverged"

    def worst(self, n: int = 3) -> list[tuple[str, float, float]]:
        """Up to n keys that left their tolerance (or came closest), largest error/tolerance first."""
        return worst_keys(self.max_abs_error, self.tolerance, n)

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "seed": self.seed,
            "length": self.length,
            "verdict": self.verdict,
            "first_divergence": None if self.first_divergence is None else self.first_divergence.to_json(),
            "max_abs_error": {k: json_number(v) for k, v in self.max_abs_error.items()},
            "diverged_keys": dict(self.diverged_keys),
            "notes": list(self.notes),
            "limits": list(self.limits),
            "seconds": round(self.seconds, 4),
        }


@dataclass
class ReplayReport:
    """All episodes of one `simreel replay` run."""

    path: str
    env_id: str
    mode: str
    resync: int | None
    tolerances: dict[str, float]
    warnings: list[str] = field(default_factory=list)
    episodes: list[EpisodeReport] = field(default_factory=list)
    output: str | None = None

    @property
    def ok(self) -> bool:
        return all(e.ok for e in self.episodes)

    def to_json(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "path": self.path,
            "env_id": self.env_id,
            "mode": self.mode,
            "resync": self.resync,
            "tolerances": dict(self.tolerances),
            "warnings": list(self.warnings),
            "output": self.output,
            "episodes": [e.to_json() for e in self.episodes],
        }

    def summary(self, *, top: int = 8) -> str:
        """The readable table `simreel replay` prints."""
        mode = self.mode + (f" --resync {self.resync}" if self.resync else "")
        steps = sum(e.length for e in self.episodes)
        lines = [f"replay of {self.path}: {self.env_id}, mode {mode}, {len(self.episodes)} episode(s), {steps} steps"]
        lines.append(f"  {'episode':>7} {'steps':>6}  {'verdict':<17} first divergence")
        for e in self.episodes:
            first = e.first_divergence.describe() if e.first_divergence else ""
            lines.append(f"  {e.index:>7} {e.length:>6}  {e.verdict:<17} {first}".rstrip())
            if not e.ok:
                also = [f"{k} {format_number(v)} (tol {format_number(t)})" for k, v, t in e.worst(4)
                        if e.first_divergence is None or k != e.first_divergence.key]
                if also:
                    n = len(e.diverged_keys)
                    lines.append(f"  {'':>7} {'':>6}  {'':<17} {n} keys left their tolerance; worst: " + ", ".join(also[:3]))
            for note in e.notes if e.verdict != "exact" else e.limits:  # what was not checked: always
                lines.append(f"  {'':>7} {'':>6}  {'':<17} note: {note}")
        if self.mode == "step" or self.resync:
            lines.append(self._per_key_table(top))
        n_exact = sum(e.verdict == "exact" for e in self.episodes)
        n_within = sum(e.verdict == "within_tolerance" for e in self.episodes)
        n_div = len(self.episodes) - n_exact - n_within
        verdict = "all verified" if n_div == 0 else f"{n_div} diverged"
        lines.append(
            f"{len(self.episodes) - n_div} of {len(self.episodes)} episode(s) verified "
            f"({n_exact} exact, {n_within} within tolerance); {verdict}"
        )
        return "\n".join(lines)

    def _per_key_table(self, top: int) -> str:
        worst: dict[str, float] = {}
        tol: dict[str, float] = {}
        for e in self.episodes:
            for k, v in e.max_abs_error.items():
                worst[k] = max(worst.get(k, 0.0), v)
                tol[k] = e.tolerance.get(k, 0.0)
        keys = sorted((k for k in worst if worst[k] > 0), key=lambda k: worst[k] / tol[k] if tol[k] else math.inf,
                      reverse=True)
        title = "one-step" if self.mode == "step" else f"resync-{self.resync}"
        lines = [f"largest {title} errors per key (all episodes):"]
        for k in keys[:top]:
            lines.append(f"  {k:<55} {format_number(worst[k]):>10}  (tolerance {format_number(tol[k])})")
        if len(keys) > top:
            lines.append(f"  ... {len(keys) - top} more keys differ; see --report")
        if not keys:
            lines.append("  none: every key was reproduced exactly")
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- the loop
@dataclass
class _Job:
    path: str
    mode: str
    resync: int | None
    tolerances: Tolerances
    obs_mode: str | None
    need_obs: bool
    pose_bodies: list[str]
    keep_episode: bool
    imports: tuple[str, ...]
    sim_backend: str | None = None


def _compare(job: _Job, recorded: Episode, replayed: Any, meta: RecordingMeta) -> EpisodeReport:
    cmp = compare_episode(
        recorded,
        replayed.episode,
        job.tolerances,
        contact_channels=meta.contact_channels,
        compare_contacts=replayed.compare_contacts,
        compare_obs=(job.obs_mode is None or job.obs_mode == meta.obs_mode),
    )
    return EpisodeReport(
        index=recorded.meta.index,
        seed=recorded.meta.seed,
        length=recorded.length,
        verdict=cmp.verdict,
        first_divergence=cmp.first_divergence,
        max_abs_error=cmp.max_abs_error,
        tolerance=cmp.tolerance,
        diverged_keys=cmp.diverged_keys,
        notes=replayed.notes,
        limits=replayed.limits,
        seconds=replayed.seconds,
    )


class _Session:
    """One reader + one replayer; lives in the main process (workers=1) or in each worker process."""

    def __init__(self, job: _Job) -> None:
        from simreel.replay.fingerprint import fingerprint_differences

        self.job = job
        self.reader = open_reader(job.path)
        try:
            meta = self.reader.meta
            if job.imports:
                meta = dataclasses.replace(meta, imports=list(dict.fromkeys([*meta.imports, *job.imports])))
            self.meta = meta
            self.replayer = EpisodeReplayer(meta, obs_mode=job.obs_mode, need_obs=job.need_obs,
                                            pose_bodies=job.pose_bodies, sim_backend=job.sim_backend)
        except BaseException:
            self.reader.close()
            raise
        self.warnings = fingerprint_differences(meta, self.replayer.u)

    def run(self, index: int) -> tuple[EpisodeReport, Episode | None]:
        recorded = self.reader.read_episode(index)
        return self._finish(recorded, self._replay(recorded))

    def _replay(self, recorded: Episode) -> Any:
        return self.replayer.replay(recorded, mode=self.job.mode, resync=self.job.resync)

    def _finish(self, recorded: Episode, replayed: Any) -> tuple[EpisodeReport, Episode | None]:
        report = _compare(self.job, recorded, replayed, self.meta)
        if not self.job.keep_episode:
            return report, None
        episode = replayed.episode
        if self.job.mode == "states":
            # states were restored from the recording; its contact forces are the true ones of the original run
            # (the replay's come from one step simulated from each restored state)
            episode = dataclasses.replace(episode, contact_forces=recorded.contact_forces)
        return report, episode

    def close(self) -> None:
        self.replayer.close()
        self.reader.close()


_WORKER: _Session | SimreelError | None = None
"""A worker process's session, or the user error that building it raised (re-raised in the parent)."""


def _worker_init(job: _Job) -> None:
    global _WORKER
    try:
        _WORKER = _Session(job)
    except SimreelError as e:  # an initializer that raises breaks the whole pool (BrokenProcessPool)
        _WORKER = e


def _worker_run(index: int) -> tuple[EpisodeReport, Episode | None] | SimreelError:
    """One episode's report and replayed episode, or the user error that stopped it (raised by the parent)."""
    if isinstance(_WORKER, SimreelError):
        return _WORKER
    if _WORKER is None:
        raise RuntimeError("_worker_run called in a process that _worker_init did not set up")
    try:
        return _WORKER.run(index)
    except SimreelError as e:
        return e


def verify_recording(
    path: str | Path,
    *,
    mode: str = "actions",
    resync: int | None = None,
    episodes: Sequence[int] | None = None,
    atol: float | None = None,
    group_tolerances: dict[str, float] | None = None,
    output: str | Path | None = None,
    overwrite: bool = False,
    obs_mode: str | None = None,
    workers: int = 1,
    imports: Iterable[str] = (),
    sim_backend: str | None = None,
    progress: Callable[[EpisodeReport], None] | None = None,
    command: str = "",
) -> ReplayReport:
    """Replay episodes of the recording at `path` in `mode` and verify each one.

    Args:
        mode: "actions", "states" or "step" (see `simreel.replay.engine`).
        resync: with mode "actions", restore the recorded state before every `resync`-th action.
        episodes: episode indices (None: all, in file order).
        atol: one absolute tolerance for every group (flags stay exact); `group_tolerances` then overrides
            single groups, e.g. ``{"contact": 5.0}``. Defaults: `simreel.compare.DEFAULT_TOLERANCES`.
        output: write the replayed episodes here (.h5 or .mcap), with observations when the recording has
            them or `obs_mode` is given.
        obs_mode: observation mode of the replay, e.g. "rgb" to re-render observations into `output`.
        workers: processes replaying episodes in parallel, each with its own env (this one and workers - 1
            more).
        imports: `--import` specs to import before rebuilding the env (besides those the recording names).
        sim_backend: replay on this backend instead of the recorded one (e.g. "physx_cpu" for a GPU
            recording: a different engine, so expect `within_tolerance` or `diverged` in actions mode).
        progress: called with each episode's report as it finishes.

    Raises:
        UsageError / RecordingFileError / EnvBuildError (exit 2 in the CLI) for bad arguments, a bad
        file, an unknown episode, an env that cannot be rebuilt; `ReplayError` when its state layout differs.
    """
    if mode not in MODES:
        raise UsageError(f"unknown --mode {mode!r}; expected one of {', '.join(MODES)}")
    if resync is not None:
        if mode != "actions":
            raise UsageError(f"--resync works with --mode actions only (got --mode {mode})")
        if resync < 1:
            raise UsageError(f"--resync must be >= 1, got {resync}")
    if workers < 1:
        raise UsageError(f"--workers must be >= 1, got {workers}")
    if output is not None:
        format_of(output)
        if Path(output).exists() and not overwrite:
            raise UsageError(f"{output} already exists; pass --overwrite to replace it")
        if Path(output).resolve() == Path(path).resolve():
            raise UsageError(f"-o {output} is the recording being replayed; write the replay to another file")
    try:
        tolerances = Tolerances.for_mode("resync" if resync else mode, atol=atol, groups=group_tolerances)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if atol is not None and (not math.isfinite(atol) or atol < 0):
        raise UsageError(f"--atol must be a number >= 0, got {atol}")

    with open_reader(path) as reader:
        meta = reader.meta
        known = [m.index for m in reader.episodes]
        if episodes is None:
            indices = known
        else:
            for i in episodes:
                reader.episode_meta(i)  # raises RecordingFileError naming the episodes the file has
            indices = list(dict.fromkeys(episodes))
    if not indices:
        raise UsageError(f"{path}: the recording has no episodes to replay")

    job = _Job(
        path=str(path),
        mode=mode,
        resync=resync,
        tolerances=tolerances,
        obs_mode=obs_mode,
        need_obs=bool(meta.obs_layout) or obs_mode is not None,
        pose_bodies=_pose_bodies(meta, output),
        sim_backend=sim_backend,
        keep_episode=output is not None,
        imports=tuple(imports),
    )
    report = ReplayReport(path=str(path), env_id=meta.env_id, mode=mode, resync=resync,
                          tolerances=tolerances.to_json(), output=None if output is None else str(output))
    sink = _OrderedWriter(output, meta, obs_mode, command, indices, job.pose_bodies) if output is not None else None
    try:
        if workers == 1 or len(indices) == 1:
            _run_here(job, indices, report, sink, progress)
        else:
            _run_workers(job, indices, min(workers, len(indices)), report, sink, progress)
    finally:
        if sink is not None:
            sink.close()
    order = {i: k for k, i in enumerate(indices)}
    report.episodes.sort(key=lambda e: order[e.index])
    return report


def _pose_bodies(meta: RecordingMeta, output: str | Path | None) -> list[str]:
    """Bodies whose poses `-o` writes: those the recording has, or every body when writing MCAP (its transforms)."""
    if output is None:
        return []
    if meta.pose_bodies:
        return list(meta.pose_bodies)
    if format_of(output) != "mcap":
        return []
    scene = meta.scene or {}
    names = list(scene.get("actors", {}))
    for art, desc in scene.get("articulations", {}).items():
        names += [f"{art}/{link}" for link in desc.get("links", [])]
    return names


def _run_here(job: _Job, indices: list[int], report: ReplayReport, sink: Any, progress: Any) -> None:
    session = _Session(job)
    report.warnings = list(session.warnings)
    try:
        for index in indices:
            _collect(session.run(index), report, sink, progress)
    finally:
        session.close()


def _collect(result: tuple[EpisodeReport, Episode | None] | SimreelError, report: ReplayReport, sink: Any,
             progress: Any) -> None:
    if isinstance(result, SimreelError):
        raise result
    ep_report, episode = result
    report.episodes.append(ep_report)
    if sink is not None:
        sink.put(episode)
    if progress is not None:
        progress(ep_report)


def _run_workers(job: _Job, indices: list[int], workers: int, report: ReplayReport, sink: Any, progress: Any) -> None:
    """This process and `workers - 1` worker processes replay the episodes, each with its own env.

    This process builds its session first, so a user error (an --import that fails, an env that does not
    build, another state layout) is raised here as a `SimreelError` before any worker starts; a worker
    returns the errors it meets instead of raising them, and they are raised here too.
    """
    import multiprocessing

    session = _Session(job)
    try:
        report.warnings = list(session.warnings)
        queue = deque(indices)
        ahead = 2 * (workers - 1)  # episodes handed to the workers at a time; the rest stay for this process
        ctx = multiprocessing.get_context("spawn")  # sapien/torch state must not be forked
        pool = ProcessPoolExecutor(max_workers=workers - 1, mp_context=ctx, initializer=_worker_init, initargs=(job,))
        pending: set[Any] = set()
        try:
            while queue or pending:
                while queue and len(pending) < ahead:
                    pending.add(pool.submit(_worker_run, queue.popleft()))
                if queue:
                    _collect(session.run(queue.popleft()), report, sink, progress)
                    done = {fut for fut in pending if fut.done()}
                else:
                    done, _ = wait(pending, return_when=FIRST_COMPLETED)
                pending -= done
                for fut in done:
                    _collect(fut.result(), report, sink, progress)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)  # on an error: the queued episodes are dropped
    finally:
        session.close()


class _OrderedWriter:
    """Writes replayed episodes to `-o` in the order they were asked for, whatever order they finish in."""

    def __init__(self, path: str | Path, meta: RecordingMeta, obs_mode: str | None, command: str,
                 order: list[int], pose_bodies: list[str]) -> None:
        self.path = Path(path)
        self.pose_bodies = pose_bodies
        self.meta = meta
        self.obs_mode = obs_mode
        self.command = command
        self.order = list(order)
        self.waiting: dict[int, Episode] = {}
        self.writer: Any = None

    def put(self, episode: Episode | None) -> None:
        if episode is None:
            return
        self.waiting[episode.meta.index] = episode
        while self.order and self.order[0] in self.waiting:
            self._write(self.waiting.pop(self.order.pop(0)))

    def _write(self, episode: Episode) -> None:
        from simreel.envs import env_versions
        from simreel.formats import open_writer

        if self.writer is None:
            m = self.meta
            obs_mode = self.obs_mode or m.obs_mode
            out_meta = dataclasses.replace(
                m,
                obs_mode=obs_mode,
                obs_layout=layout_of(episode.obs, batched=True) if episode.obs else {},
                contact_channels=list(m.contact_channels) if episode.contact_forces is not None else [],
                pose_bodies=list(self.pose_bodies) if episode.body_poses is not None else [],
                versions={k: v for k, v in env_versions().items() if v is not None},
                created_utc=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                command=self.command,
            )
            self.writer = open_writer(self.path, out_meta, overwrite=True)
        ep_meta = dataclasses.replace(episode.meta, length=episode.length)
        if episode.length:
            ep_meta.success = bool(episode.success[-1])
            ep_meta.ever_success = bool(np.any(episode.success))
        self.writer.write_episode(dataclasses.replace(episode, meta=ep_meta))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
