"""Replay recordings and verify every episode: the run behind `simreel replay`.

A `ReplayRun` takes recordings — files, folders of them, glob patterns — and makes one work list of their
episodes (`simreel.replay.run.worklist`), ordered so each worker reuses its env. It replays them in this process,
in worker processes (``workers=N``: this one and N - 1 more, `simreel.replay.run.pool`) or on a Ray cluster
(``ray=...``: `simreel.replay.run.ray_pool`), compares each with its recording (`simreel.verdicts.compare`) and counts the
verdicts in a `RunTally` (`simreel.replay.report.tally`): ``exact``, ``within_tolerance``, ``diverged`` — with the first
divergence (step, key path, error, tolerance) and the largest error per key — or ``error`` (the episode could not
be replayed). With ``report`` the verdicts stream into REPORT.jsonl as they come and REPORT.json is written at the
end (`simreel.replay.report.log`); ``resume`` continues such a report. With ``output`` the replayed episodes of one
recording are written as a simreel recording (`simreel.replay.run.output`), in the run's scratch folder, and moved
to their name once the run is done: a run that stops or is killed leaves no part of itself there.

A run with one recording file is strict: an env that does not build for it raises (the CLI's one line, exit 2).
A dataset run (several files, a folder, a pattern) reports such errors per file and episode and goes on.
`verify_recording(path, ...)` is a one-file run kept whole in a `ReplayReport`.
"""

from __future__ import annotations

import contextlib
import datetime
import functools
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from simreel import __version__
from simreel.datasets.inputs import file_identity
from simreel.errors import FileProblemError, ReplayError, ReportFileError, StorageError, UsageError
from simreel.formats import check_report_writable, check_writable, format_of, recording_files
from simreel.io.durable import is_storage_error, raise_if_stopped, storage_error
from simreel.io.targets import check_distinct
from simreel.model.meta import RecordingMeta
from simreel.model.selection import EpisodeSelection
from simreel.options.checks import (
    options_with,
    path_list,
    path_text,
)
from simreel.replay.report.log import LoggedRun, ReportLog, load_log, report_paths, tally_of_log, write_report
from simreel.replay.report.report import EpisodeReport, recording_limits
from simreel.replay.report.tally import FileTally, ReplayReport, RunTally
from simreel.replay.run.job import EpisodeResult, ReplayJob
from simreel.replay.run.options import ReplayOptions, json_value
from simreel.replay.run.output import (
    ReplayedWriter,
    ReplayOutput,
    ScratchFolder,
    publish_checked,
    published,
    staged_path,
)
from simreel.replay.run.pool import Lanes, WorkerDiedError, pool_closing, run_pool, start_pool
from simreel.replay.run.workers import ReplayWorker
from simreel.replay.run.worklist import (
    LACKING_LISTED,
    RecordingInfo,
    WorkItem,
    WorkList,
    build_worklist,
    chain_groups,
)
from simreel.sim.user_code import import_user_code, recorded_spec, refuse_untrusted_imports

__all__ = ["ReplayOptions", "ReplayRun", "verify_recording"]

Progress = Callable[[WorkItem, EpisodeReport], None]
"""Called with each episode's report as it finishes."""


def _run_options(run: Mapping[str, Any]) -> dict[str, Any]:
    """The verdict options of a report's run line, its ``--import`` files found where that run found them: from its
    working folder (a report of a run before imports were kept absolute names them relative to it)."""
    options = dict(run["options"])
    # its text, as this run's options put it (`json_value`); a report of an earlier simreel holds a list of indices
    options["episodes"] = json_value(EpisodeSelection.of(options.get("episodes")))
    options["imports"] = [recorded_spec(spec, base=run.get("cwd")) for spec in options.get("imports") or ()]
    return options


class ReplayRun:
    """One replay-and-verify run over recordings: checked and ready when built, done by `execute`.

    Building it checks the options and every output, reads each recording's header (metadata and episode list:
    `worklist`) and, when resuming, the report; nothing is replayed or written yet.
    """

    def __init__(self, inputs: str | Path | Sequence[str | Path], options: ReplayOptions | None = None,
                 **overrides: Any) -> None:
        opts = options_with(ReplayOptions, options, overrides, 'ReplayRun(paths, mode="step")')
        self.options = opts
        self.tolerances = opts.tolerances()
        self.inputs = _input_paths(inputs)
        if not self.inputs:
            raise UsageError("no recordings to replay: name files, folders or patterns")
        self.strict = len(self.inputs) == 1 and Path(self.inputs[0]).is_file()
        """One recording file: an error of its env raises instead of being reported per episode."""
        self.report_json, self.report_log = report_paths(opts.report) if opts.report else (None, None)
        logged = self._logged()
        restores = f"--mode {opts.mode}" if opts.mode != "actions" else ("--resync" if opts.resync else None)
        self.worklist: WorkList = build_worklist(self._recordings(logged), episodes=opts.episodes,
                                                 restores=restores, done=logged.done if logged else (),
                                                 chains=opts.mode == "actions")
        if logged is not None:
            self._check_logged_episodes(logged)
        self._check_outputs()
        self.tally = self._tally(logged)
        self._new_files = [f for f in self.worklist.files if logged is None or f.path not in logged.files]
        self._report_begun = logged is not None
        """Whether `report` holds this run's lines: a resumed one, or once `_log` has begun it."""
        if self.strict and not self.worklist.items and logged is None:
            raise UsageError(f"{self.inputs[0]}: the recording has no episodes to replay")
        if opts.episodes and logged is None and self.worklist.readable and not self.worklist.items:
            raise UsageError(f"--episodes {opts.episodes}: none of the recordings has any of these episodes")
        self._refuse_untrusted_imports()
        for spec in opts.imports:  # a bad --import is one line now, not an error for every episode
            import_user_code(spec)

    @classmethod
    def resume(cls, report: str | Path, **execution: Any) -> ReplayRun:
        """Continue the run that wrote `report`, with its inputs and verdict options; `execution` may change how it
        runs (workers, ray, ship, command), not what decides a verdict."""
        allowed = {"workers", "ray", "ship", "trust_recorded_imports", "command"}
        if set(execution) - allowed:
            raise UsageError(f"a resumed run takes its options from the report; only {', '.join(sorted(allowed))} "
                             f"may change, not {', '.join(sorted(set(execution) - allowed))}")
        report = path_text("report", report, "the report to continue, a str or pathlib.Path (REPORT.json)")
        _, log = report_paths(report)
        run = load_log(log).run
        options = ReplayOptions(**_run_options(run), report=report, resume=True, **execution)
        return cls(run["inputs"], options)

    # ------------------------------------------------------------------ checks
    def _logged(self) -> LoggedRun | None:
        """The report being resumed, checked against this run's options and files."""
        opts = self.options
        if not opts.resume:
            return None
        logged = load_log(self.report_log)
        if logged.run.get("output"):
            raise UsageError(f"{self.report_json}: its run wrote replayed episodes (-o), which cannot be resumed; "
                             "run it again with --overwrite")
        mine = opts.verdict_options()
        for name, value in _run_options(logged.run).items():
            if mine.get(name) != value:
                raise UsageError(f"{self.report_json} was made with {name}={value!r} and this run asks for "
                                 f"{name}={mine.get(name)!r}; resume with the report's options (simreel replay "
                                 f"--resume {self.report_json} alone)")
        self._check_unchanged(logged)
        return logged

    def _recordings(self, logged: LoggedRun | None) -> list[str]:
        """What the work list is made of: the inputs; for a resumed run, the recordings the report's run listed
        (its file lines), not what its folders and patterns hold now. Its unreadable files are not read again
        (the report keeps why); a report cut before its run had listed them all has no verdict yet: its inputs."""
        if logged is None or len(logged.files) < logged.run.get("files", 1):
            return self.inputs
        return [path for path, f in logged.files.items() if f.get("error") is None]

    def _check_outputs(self) -> None:
        opts = self.options
        inputs = [side for f in self.worklist.files for side in recording_files(f.path)]
        outputs: dict[str, list[Path]] = {}
        if opts.output is not None:
            if not self.strict:
                raise UsageError("-o writes the replayed episodes of one recording; name one file to replay")
            format_of(opts.output)
            outputs["-o"] = recording_files(opts.output)
        if self.report_json is not None:
            outputs["--report"] = [self.report_json, self.report_log]
        check_distinct(outputs, inputs, input_label="a recording being replayed")
        if opts.output is not None:
            check_writable(opts.output, overwrite=opts.overwrite)
        if self.report_json is not None and not opts.resume:
            check_report_writable(self.report_json, overwrite=opts.overwrite, side_paths=[self.report_log],
                                  option="--report")

    def _refuse_untrusted_imports(self) -> None:
        """One line before any work where this run would import code that came with its data without the user's
        word: the imports of a report it resumes, or those a recording names (`refuse_untrusted_imports`)."""
        opts = self.options
        trust = opts.trust_recorded_imports
        if opts.resume:
            refuse_untrusted_imports(opts.imports, trust=trust, source=self.report_json, what="report")
        for f in self.worklist.readable:
            refuse_untrusted_imports(f.meta.imports, explicit=opts.imports, trust=trust, source=f.path)

    def _check_unchanged(self, logged: LoggedRun) -> None:
        """A resumed run must replay the files the report began with, every one of them, not newer versions."""
        for path, then in logged.files.items():
            if then.get("error") is not None:
                continue  # unreadable then: the report says why, and nothing of it is replayed
            try:
                now = file_identity(path)
            except OSError:
                raise UsageError(f"{path} is gone since {self.report_json} began: its episodes cannot be replayed; "
                                 "put it back to resume, or start a new report (--overwrite)") from None
            if (then.get("size"), then.get("mtime_ns")) != now:
                raise UsageError(f"{path} changed since {self.report_json} began (size or modification time "
                                 "differ): its verdicts would mix two recordings; start a new report (--overwrite)")

    def _check_logged_episodes(self, logged: LoggedRun) -> None:
        """Every verdict of the report is on an episode this run replays, and every file it lists plans the
        episodes the file has: else the report is damaged, and a resumed run would count verdicts of nothing."""
        planned = {f.path: f.episodes for f in self.worklist.files if f.meta is not None}
        for (path, index), number in logged.done.items():
            if index not in planned.get(path, {}):
                raise ReportFileError(self.report_log, f"line {number} gives a verdict on episode {index} of {path}, "
                                                       "which the run does not replay: the report is damaged")
        for path, number in logged.file_lines.items():
            listed = logged.files[path]["episodes"]
            if path in planned and listed != len(planned[path]):
                raise ReportFileError(self.report_log, f"line {number} plans {listed} episode(s) of {path}, and the run "
                                                       f"replays {len(planned[path])}: the report is damaged")

    def _tally(self, logged: LoggedRun | None) -> RunTally:
        opts = self.options
        tally = tally_of_log(self.report_log) if logged else RunTally(opts.mode, opts.resync, self.tolerances.to_json())
        for f in self.worklist.files:
            tally.add_file(_file_tally(f))
        return tally

    # ------------------------------------------------------------------ running
    @property
    def total(self) -> int:
        """Episodes this run replays."""
        return len(self.worklist.items)

    def _job(self, scratch: str | None = None) -> ReplayJob:
        opts = self.options
        return ReplayJob(mode=opts.mode, resync=opts.resync, tolerances=self.tolerances, obs_mode=opts.obs_mode,
                         sim_backend=opts.sim_backend, output=opts.output, imports=opts.imports,
                         trust_imports=opts.trust_recorded_imports, scratch=scratch)

    def execute(self, progress: Progress | None = None) -> RunTally:
        """Replay every episode of the work list, calling `progress` as each finishes; returns the run's tally
        (a resumed run's includes the verdicts it found in the report). Raises the user errors (`SimreelError`)
        a strict run meets; Ctrl-C stops it with every verdict reached so far in the report."""
        with self._scratch() as folder:
            shared = None if folder is None or self.options.ray is not None else str(folder.path)
            return self._execute(ReplayWorker(self._job(shared)), progress, folder)

    @contextlib.contextmanager
    def _scratch(self) -> Iterator[ScratchFolder | None]:
        """The run's scratch folder for `-o` (`ScratchFolder`), removed when the run ends, however it ends: `-o` is
        written there until the run is done (`_sink`), and a pool's workers write their episodes there (not on Ray:
        its actors need not share this file system, they return their episodes whole); the pool is shut down inside
        it, so no worker writes there after. None without `-o`."""
        if self.options.output is None:
            yield None
            return
        with ScratchFolder(self.options.output) as folder:
            yield folder

    def _execute(self, worker: ReplayWorker, progress: Progress | None, folder: ScratchFolder | None) -> RunTally:
        ended = False
        try:
            with pool_closing(self._start_pool(worker.job)) as pool:
                if self.strict and self.worklist.items and self.options.ray is None:
                    worker.prepare(self.worklist.items[0])  # a bad env fails before anything is written
                with self._log() as log:
                    with self._sink(folder) as sink:  # -o is published (or fails) as this block ends, before the end line
                        worker.output = sink if self.options.ray is None else None  # replayed here: streamed into -o
                        self._dispatch(worker, self._collector(log, sink, progress), log, pool)
                    if log is not None:
                        log.write({"type": "end"})
            ended = True
        except WorkerDiedError as e:
            advice = "(with fewer --workers if memory ran out)" if e.memory else ""
            raise ReplayError(f"{e}; {self.how_to_finish(advice)}") from None
        finally:
            worker.close()
            self._write_report(ended)
        return self.tally

    def how_to_finish(self, advice: str = "") -> str:
        """What a run that stopped early kept and the command that finishes it (`advice` goes with it): a resume of
        its report, except for a run that wrote replayed episodes (-o), which `--resume` refuses (`_logged`)."""
        advice = f" {advice}" if advice else ""
        if self.options.output is not None:
            return (f"{self.options.output} was not written; run it again{advice} (a run that writes replayed episodes "
                    "cannot be resumed)")
        if self.report_json is None:
            return f"run it again{advice} (with --report, a stopped run keeps its verdicts for --resume)"
        if not self._report_begun:  # stopped while it started: a file there now is not this run's
            return f"{self.report_json} was not begun (no episode had its verdict yet): run it again{advice}"
        trust = " --trust-recorded-imports" if self.options.imports or self.options.trust_recorded_imports else ""
        return (f"{self.tally.total} of {self.tally.planned} episodes have their verdict in {self.report_json}; "
                f"finish with: simreel replay --resume {self.report_json}{trust}{advice}")

    def _write_report(self, ended: bool) -> None:
        """Write REPORT.json from the lines. When the run ended well, a storage error doing so is the run's one line
        (the lines hold every verdict: a resume writes it); after another error, that error is the one told."""
        if self.report_log is None or not self.report_log.exists():
            return
        try:
            write_report(self.report_log, self.report_json, output=self.options.output)
        except Exception as e:
            if not ended:
                return  # the error that stopped the run is the one to tell; the lines keep its verdicts
            if not is_storage_error(e):
                raise
            error = storage_error(self.report_json, e)
            raise StorageError(self.report_json, error.reason, f"{error.fix}, then write it with: simreel replay "
                               f"--resume {self.report_json}", f": every verdict is in {self.report_log}") from None

    @contextlib.contextmanager
    def _log(self) -> Iterator[ReportLog | None]:
        if self.report_log is None:
            yield None
            return
        with ReportLog(self.report_log, resume=self.options.resume) as log:
            self._report_begun = True
            log.write(self._run_line())
            for f in self._new_files:
                log.write({"type": "file", **self.tally.files[f.path].to_json()})
            yield log

    def _run_line(self) -> dict[str, Any]:
        opts = self.options
        return {"type": "run", "simreel": __version__, "resumed": opts.resume, "cwd": os.getcwd(),
                "started_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                "inputs": [os.path.abspath(p) for p in self.inputs], "files": len(self.worklist.files),
                "options": opts.verdict_options(),
                "tolerances": self.tolerances.to_json(), "output": opts.output, "command": opts.command}

    @contextlib.contextmanager
    def _sink(self, folder: ScratchFolder | None) -> Iterator[ReplayedWriter | None]:
        """The writer of `-o`, which writes it in the run's scratch `folder` and moves it to its name once every
        episode is in it (`publish_checked`): `-o` never holds part of a run, even after a kill -9, and an old file
        there stays as it was until then. None without `-o`."""
        opts = self.options
        if opts.output is None or folder is None:
            yield None
            return
        f = self.worklist.files[0]
        job = self._job()
        staged = staged_path(folder)
        spec = ReplayOutput(str(staged), True, opts.obs_mode, job.replayer_options(f.meta).pose_bodies,
                            opts.command, changes={"provenance": self._provenance(f.path, f.meta)})
        writer = ReplayedWriter(spec, f.meta, list(f.episodes))
        with published(writer, final=opts.output) as sink:
            yield sink
        if staged.is_file():
            publish_checked(staged, opts.output, f.meta, overwrite=opts.overwrite)

    def _provenance(self, path: str | Path, meta: RecordingMeta) -> dict[str, Any]:
        """What `-o` writes says of where it came from (`RecordingMeta.provenance`): the replay of the recording
        `meta` at `path`, its mode and the tolerances that judged each episode, which `simreel view --compare` and
        `video --compare` judge it with again; that recording's own provenance, if it has one, kept as ``input``."""
        opts = self.options
        made = {"operation": "replay", "source": str(Path(path).resolve()), "source_recording_id": meta.recording_id,
                "mode": opts.mode, "resync": opts.resync, "tolerances": self.tolerances.to_json()}
        return {**made, "input": meta.provenance} if meta.provenance else made

    def _collector(self, log: ReportLog | None, sink: ReplayedWriter | None,
                   progress: Progress | None) -> Callable[[EpisodeResult], None]:
        def collect(result: EpisodeResult) -> None:
            raise_if_stopped()  # a Ctrl-C that landed in a finalizer was printed and dropped by Python
            item = result.item
            report = self._report_of(result)
            if not self.tally.add(item.path, report, result.warnings):
                return  # an episode replayed twice (a retried Ray task): its first verdict stands
            if log is not None:
                log.episode(item.path, report, warnings=result.warnings, worker=result.worker)
            if sink is not None:
                sink.put(item.index, result.scratch or result.episode)
            if progress is not None:
                progress(item, report)

        return collect

    def _report_of(self, result: EpisodeResult) -> EpisodeReport:
        if result.error is None:
            assert result.report is not None
            return result.report
        if self.strict and result.env_error:
            raise result.error
        error = result.error
        why = error.problem if isinstance(error, FileProblemError) else str(error)  # the file is named beside it
        return EpisodeReport.errored(result.item.index, result.item.steps, why)

    @functools.cached_property
    def _local_workers(self) -> int:
        """Processes of the local pool (this one included); 1: no pool. No more than the run has groups of items
        (`chain_groups`): an actions replay replays the episodes of one scene chain in one process."""
        if self.options.ray is not None:
            return 1
        return min(self.options.workers, len(chain_groups(self.worklist.items)))

    def _start_pool(self, job: ReplayJob) -> Lanes | None:
        """The local pool's processes, started before this process builds its env so that both happen at once;
        each builds the env of the first item (the list is ordered by env key: most need no other)."""
        if self._local_workers <= 1:
            return None
        return start_pool(job, self._local_workers, self.worklist.items[0])

    def _note(self, text: str, log: ReportLog | None) -> None:
        self.tally.notes.append(text)
        if log is not None:
            log.write({"type": "note", "text": text})

    def _dispatch(self, worker: ReplayWorker, collect: Callable[[EpisodeResult], None], log: ReportLog | None,
                  pool: Lanes | None) -> None:
        items = self.worklist.items
        opts = self.options
        if opts.ray is not None:
            from simreel.replay.run.ray_pool import RayOptions, run_ray

            notes = run_ray(worker.job, items, RayOptions(opts.ray, opts.workers, opts.ship), self.worklist.readable,
                            collect)
            for note in notes:
                self._note(note, log)
            return
        if self._local_workers < min(opts.workers, len(items)):  # chains, not episodes, limit the processes
            self._note(_few_chains_note(opts.workers, self._local_workers, len(items)), log)
        if pool is None:
            for item in items:
                collect(worker.run(item))
        else:
            run_pool(worker, items, self._local_workers, collect, pool)


def _few_chains_note(asked: int, chains: int, episodes: int) -> str:
    """Why fewer processes replay than `--workers` asked for: the `episodes` form `chains` scene chains."""
    processes, form = ("1 process", "1 scene chain") if chains == 1 else (f"{chains} processes", f"{chains} scene chains")
    return (f"--workers {asked}: {processes} replayed these {episodes} episodes, which form {form} "
            "(episodes that ran one after another in one scene since it was built); an actions replay replays each "
            "chain in turn in one process (PhysX results depend on the scene's history)")


def _input_paths(inputs: Any) -> list[str]:
    """`ReplayRun`'s inputs as a list of strings: one path (a str or `pathlib.Path`) or several; `UsageError` for
    anything else, which would be taken for a file name (a number) or fail as a raw TypeError."""
    return path_list("inputs", inputs, "the recordings to replay (files, folders or glob patterns) as a str or "
                                       "pathlib.Path, or a list of them")


def _file_tally(f: RecordingInfo) -> FileTally:
    return FileTally(f.path, f.meta.env_id if f.meta else None, len(f.episodes), size=f.size, mtime_ns=f.mtime_ns,
                     error=f.error, limits=recording_limits(f.meta.unknown) if f.meta else [],
                     warnings=_lacking_warning(f))


def _lacking_warning(f: RecordingInfo) -> list[str]:
    """What a dataset run says of a file that lacks episodes --episodes names (it replays those it has)."""
    if not f.lacking:
        return []
    lacking = ", ".join(map(str, f.lacking[:LACKING_LISTED])) + (", ..." if len(f.lacking) > LACKING_LISTED else "")
    if not f.episodes:
        return [f"has none of the episodes --episodes names (no episode {lacking}): nothing of it is replayed"]
    return [f"has no episode {lacking} of those --episodes names: only its episode(s) "
            f"{', '.join(map(str, f.episodes))} are replayed"]


def verify_recording(
    path: str | Path,
    options: ReplayOptions | None = None,
    *,
    progress: Callable[[EpisodeReport], None] | None = None,
    **overrides: Any,
) -> ReplayReport:
    """Replay episodes of the recording at `path` and verify each one, keeping every report: a `ReplayRun` of one
    file. `overrides` are `ReplayOptions` fields, e.g. ``verify_recording("rec.h5", mode="step", episodes=[0, 3])``.

    Raises:
        UsageError / RecordingFileError / EnvBuildError (exit 2 in the CLI) for bad arguments, a bad
        file, an unknown episode, an env that cannot be rebuilt; `StateLayoutError` when its layout differs.
    """
    run = ReplayRun(path, options, **overrides)
    if len(run.worklist.files) != 1:
        files = [str(f.path) for f in run.worklist.files]
        names = ", ".join(files[:3]) + (", ..." if len(files) > 3 else "")
        raise UsageError(f"verify_recording verifies one recording, and {path} names {len(files)} ({names}): pass "
                         "one file, or use ReplayRun for several")
    reports: dict[int, EpisodeReport] = {}

    def keep(item: WorkItem, report: EpisodeReport) -> None:
        reports[item.index] = report
        if progress is not None:
            progress(report)

    tally = run.execute(keep)
    (f,) = run.worklist.files
    (counted,) = tally.files.values()
    return ReplayReport(path=str(path), env_id=f.meta.env_id, mode=run.options.mode, resync=run.options.resync,
                        tolerances=run.tolerances.to_json(), warnings=list(counted.warnings),
                        episodes=[reports[i] for i in f.episodes if i in reports], output=run.options.output,
                        limits=list(counted.limits))
