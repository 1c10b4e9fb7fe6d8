"""Replay a recording and verify every episode: the loop behind `simreel replay`.

`verify_recording(path, mode=..., ...)` replays the chosen episodes (in this process, or with ``workers=N``
in this one and N - 1 worker processes, each with its own env: `simreel.replay.workers`), compares each with
its recording (`simreel.compare`) and returns a `ReplayReport` (`simreel.replay.report`): one `EpisodeReport`
per episode with its verdict (``exact``, ``within_tolerance`` or ``diverged``), the first divergence (step,
key path, error, tolerance) and the largest error per key. With ``output`` it also writes the replayed
episodes as a simreel recording (`simreel.replay.output`).

`ReplayRun` is the same in two steps, for callers that want to know what will run before it does (the CLI's
progress bar): building it opens the recording once and checks every option; `execute` replays.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simreel.compare import Tolerances
from simreel.errors import UsageError
from simreel.formats import EpisodeReader, check_writable, format_of, open_reader, recording_files
from simreel.formats.targets import check_distinct
from simreel.replay.engine import MODES, ReplayerOptions
from simreel.replay.output import ReplayedWriter, ReplayOutput, output_pose_bodies
from simreel.replay.report import EpisodeReport, ReplayReport, recording_limits
from simreel.replay.workers import EpisodeResult, ReplayJob, ReplaySession, run_pool

__all__ = ["ReplayOptions", "ReplayRun", "verify_recording"]


@dataclass(frozen=True)
class ReplayOptions:
    """How `verify_recording` replays and judges a recording.

    Attributes:
        mode: "actions", "states" or "step" (see `simreel.replay.engine`).
        resync: with mode "actions", restore the recorded state before every `resync`-th action.
        episodes: episode indices (None: all, in file order).
        atol: one absolute tolerance for every group (flags stay exact); `group_tolerances` then overrides
            single groups, e.g. ``{"contact": 5.0}``. Defaults: `simreel.compare.DEFAULT_TOLERANCES`.
        output: write the replayed episodes here (.h5 or .mcap), with observations when the recording has
            them or `obs_mode` is given; `overwrite` lets it replace an existing recording.
        obs_mode: observation mode of the replay, e.g. "rgb" to re-render observations into `output`.
        workers: processes replaying episodes in parallel, each with its own env (this one and workers - 1
            more).
        imports: `--import` specs to import before rebuilding the env, instead of those the recording names
            (which are otherwise found as `simreel.sim.user_code.resolve_task_imports` says).
        sim_backend: replay on this backend instead of the recorded one (e.g. "physx_cpu" for a GPU
            recording: a different engine, so expect `within_tolerance` or `diverged` in actions mode).
        command: the command line, kept in `output`'s metadata.
    """

    mode: str = "actions"
    resync: int | None = None
    episodes: tuple[int, ...] | None = None
    atol: float | None = None
    group_tolerances: Mapping[str, float] = field(default_factory=dict)
    output: str | None = None
    overwrite: bool = False
    obs_mode: str | None = None
    workers: int = 1
    imports: tuple[str, ...] = ()
    sim_backend: str | None = None
    command: str = ""

    def __post_init__(self) -> None:
        if self.episodes is not None:
            object.__setattr__(self, "episodes", tuple(self.episodes))
        object.__setattr__(self, "imports", tuple(self.imports))
        if self.output is not None:
            object.__setattr__(self, "output", str(self.output))

    def tolerances(self) -> Tolerances:
        """The tolerances these options ask for; `UsageError` for a bad mode, resync, worker count or tolerance."""
        if self.mode not in MODES:
            raise UsageError(f"unknown --mode {self.mode!r}; expected one of {', '.join(MODES)}")
        if self.resync is not None and self.mode != "actions":
            raise UsageError(f"--resync works with --mode actions only (got --mode {self.mode})")
        if self.resync is not None and self.resync < 1:
            raise UsageError(f"--resync must be >= 1, got {self.resync}")
        if self.workers < 1:
            raise UsageError(f"--workers must be >= 1, got {self.workers}")
        if self.atol is not None and (not math.isfinite(self.atol) or self.atol < 0):
            raise UsageError(f"--atol must be a number >= 0, got {self.atol}")
        try:
            return Tolerances.for_mode("resync" if self.resync else self.mode, atol=self.atol,
                                       groups=self.group_tolerances)
        except ValueError as e:
            raise UsageError(str(e)) from None


class ReplayRun:
    """One replay-and-verify run over a recording: checked and ready when built, done by `execute`.

    Building it checks the options and the `-o` target, opens the recording (the one time this process
    does) and resolves the episodes; `total` says how many will be replayed.
    """

    def __init__(self, path: str | Path, options: ReplayOptions | None = None, **overrides: Any) -> None:
        opts = dataclasses.replace(options or ReplayOptions(), **overrides)
        self.path = str(path)
        self.options = opts
        self.tolerances = opts.tolerances()
        if opts.output is not None:
            format_of(opts.output)
            check_distinct({"-o": recording_files(opts.output)}, recording_files(path),
                           input_label="the recording being replayed")
            check_writable(opts.output, overwrite=opts.overwrite)
        self.reader: EpisodeReader = open_reader(path)
        try:
            self._check_mode()
            self.indices = self._indices()
        except BaseException:
            self.reader.close()
            raise

    def _check_mode(self) -> None:
        """Modes that restore recorded states need a file that holds them."""
        opts = self.options
        if (opts.mode != "actions" or opts.resync) and not self.reader.meta.state_layout:
            what = f"--mode {opts.mode}" if opts.mode != "actions" else "--resync"
            raise UsageError(f"{what} restores recorded states and {self.path} holds none (recorded without "
                             "env_states); replay it with --mode actions")

    def _indices(self) -> list[int]:
        episodes = self.options.episodes
        if episodes is None:
            indices = [m.index for m in self.reader.episodes]
        else:
            for i in episodes:
                self.reader.episode_meta(i)  # raises RecordingFileError naming the episodes the file has
            indices = list(dict.fromkeys(episodes))
        if not indices:
            raise UsageError(f"{self.path}: the recording has no episodes to replay")
        return indices

    def close(self) -> None:
        """Close the recording (`execute` does; call it when a run is not executed)."""
        self.reader.close()

    def __enter__(self) -> ReplayRun:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def total(self) -> int:
        """Episodes this run replays."""
        return len(self.indices)

    def _job(self) -> ReplayJob:
        opts, meta = self.options, self.reader.meta
        replayer = ReplayerOptions(obs_mode=opts.obs_mode, need_obs=bool(meta.obs_layout) or opts.obs_mode is not None,
                                   pose_bodies=output_pose_bodies(meta, opts.output), sim_backend=opts.sim_backend)
        return ReplayJob(path=self.path, mode=opts.mode, resync=opts.resync, tolerances=self.tolerances,
                         replayer=replayer, keep_episode=opts.output is not None, imports=tuple(opts.imports))

    def execute(self, progress: Callable[[EpisodeReport], None] | None = None) -> ReplayReport:
        """Replay every episode, calling `progress` with each episode's report as it finishes; closes the
        recording. Raises the user errors (`SimreelError`) a session meets: bad env, another layout, ..."""
        opts, meta = self.options, self.reader.meta
        job = self._job()
        report = ReplayReport(path=self.path, env_id=meta.env_id, mode=opts.mode, resync=opts.resync,
                              tolerances=self.tolerances.to_json(), output=opts.output,
                              limits=recording_limits(meta.unknown))
        sink = None
        if opts.output is not None:
            spec = ReplayOutput(opts.output, opts.overwrite, opts.obs_mode, job.replayer.pose_bodies, opts.command)
            sink = ReplayedWriter(spec, meta, self.indices)

        def collect(result: EpisodeResult) -> None:
            episode_report, episode = result
            report.episodes.append(episode_report)
            if sink is not None:
                sink.put(episode)
            if progress is not None:
                progress(episode_report)

        try:
            self._replay(job, report, collect)
        finally:
            if sink is not None:
                sink.close()
        order = {i: k for k, i in enumerate(self.indices)}
        report.episodes.sort(key=lambda e: order[e.index])
        return report

    def _replay(self, job: ReplayJob, report: ReplayReport, collect: Callable[[EpisodeResult], None]) -> None:
        session = ReplaySession(job, self.reader)  # the session closes the reader
        try:
            report.warnings = list(session.warnings)
            workers = min(self.options.workers, len(self.indices))
            if workers == 1:
                for index in self.indices:
                    collect(session.run(index))
            else:
                run_pool(session, self.indices, workers, collect)
        finally:
            session.close()


def verify_recording(
    path: str | Path,
    options: ReplayOptions | None = None,
    *,
    progress: Callable[[EpisodeReport], None] | None = None,
    **overrides: Any,
) -> ReplayReport:
    """Replay episodes of the recording at `path` and verify each one: `ReplayRun(path, options,
    **overrides).execute(progress)`. `overrides` are `ReplayOptions` fields, e.g.
    ``verify_recording("rec.h5", mode="step", episodes=[0, 3])``.

    Raises:
        UsageError / RecordingFileError / EnvBuildError (exit 2 in the CLI) for bad arguments, a bad
        file, an unknown episode, an env that cannot be rebuilt; `StateLayoutError` when its layout differs.
    """
    with ReplayRun(path, options, **overrides) as run:
        return run.execute(progress)
