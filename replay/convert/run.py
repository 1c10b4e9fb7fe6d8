"""One conversion, from its options to its checked, published output (`ConversionRun`): the input checked, the
episodes converted here or here and in pool processes (`simreel.replay.convert.worker`), the output read back and
checked in the run's scratch folder before it takes its name."""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from simreel.datasets.digests import field_digests
from simreel.errors import OutputCheckError, UsageError
from simreel.formats import check_writable, format_of, open_reader, recording_files
from simreel.io.durable import raise_if_stopped
from simreel.io.targets import check_distinct
from simreel.model.lineage import ScenePlace
from simreel.model.meta import RecordingMeta, new_recording_id
from simreel.options.checks import options_with
from simreel.replay.convert.control import check_pair
from simreel.replay.convert.job import ConvertJob, ConvertResult, states_tolerances
from simreel.replay.convert.options import ConvertOptions
from simreel.replay.convert.report import ConversionReport, checked_text
from simreel.replay.convert.tracking import tracking_tolerances
from simreel.replay.convert.worker import ConvertWorker, compares_obs
from simreel.replay.report.report import WITH_ENV_STATES, EpisodeReport, recording_limits
from simreel.replay.run.engine import GPU_SIM_BACKENDS
from simreel.replay.run.output import (
    ReplayedWriter,
    ReplayOutput,
    ScratchFolder,
    publish_checked,
    published,
    staged_path,
)
from simreel.replay.run.pool import run_pool
from simreel.replay.run.worklist import WorkItem
from simreel.sim.user_code import refuse_untrusted_imports
from simreel.verdicts.scene_history import SceneChains, run_scenes

__all__ = ["ConversionRun"]

_TRACKING_LIMITS = ("versions", "sim_config", "scene_seeds", "reset_options", "env_idx", "success")
"""What a file may not hold that limits a control-mode conversion's check (`RecordingMeta.unknown`)."""


class ConversionRun:
    """One conversion: checked and ready when built (options, output, input, episodes), done by `execute`."""

    def __init__(self, src: str | Path, dst: str | Path, options: ConvertOptions | None = None, **overrides: Any) -> None:
        opts = options_with(ConvertOptions, options, overrides, 'ConversionRun(src, dst, obs_mode="rgb")')
        opts.check()
        self.path, self.output, self.options = str(src), str(dst), opts
        format_of(dst)
        check_distinct({"OUT": recording_files(dst)}, recording_files(src), input_label="IN")
        check_writable(dst, overwrite=opts.overwrite)
        self.reader = open_reader(src)
        try:
            self._check_input(self.reader.meta)
            self.indices = self._indices()
            self.tolerances = (tracking_tolerances(opts.group_tolerances) if opts.control_mode
                               else states_tolerances())
        except BaseException:
            self.reader.close()
            raise

    def _check_input(self, meta: RecordingMeta) -> None:
        opts = self.options
        refuse_untrusted_imports(meta.imports, explicit=opts.imports, trust=opts.trust_recorded_imports,
                                 source=self.path)
        if not meta.state_layout:
            raise UsageError(f"{self.path} holds no env_states: a conversion restores or is checked against the "
                             f"recorded states; {WITH_ENV_STATES}")
        if opts.control_mode is not None:
            if opts.converter is None:
                check_pair(meta.control_mode, opts.control_mode)
            backend = opts.sim_backend or meta.sim_backend
            if backend in GPU_SIM_BACKENDS or (meta.num_envs > 1 and opts.sim_backend is None):
                raise UsageError(f"{self.path} was recorded on the GPU sim ({meta.sim_backend}, {meta.num_envs} envs); "
                                 "control-mode conversion runs on the CPU sim only (as ManiSkill's): add --sim-backend "
                                 "physx_cpu (another engine: the tracking check says how far the result is)")

    def _indices(self) -> list[int]:
        episodes = self.options.episodes
        if episodes is None:
            indices = [m.index for m in self.reader.episodes]
        else:
            indices = self.reader.named_episodes(episodes)
        indices = indices[: self.options.count]
        if not indices:
            raise UsageError(f"{self.path}: the recording has no episodes to convert")
        return indices

    @property
    def total(self) -> int:
        return len(self.indices)

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> ConversionRun:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _limits(self, meta: RecordingMeta) -> list[str]:
        """What the check cannot cover because the input does not hold it (a re-render checks what a replay in
        mode 'states' checks; tracking needs only states and success)."""
        unknown = [u for u in meta.unknown if u != "env_states"]
        if self.options.control_mode:
            unknown = [u for u in unknown if u in _TRACKING_LIMITS]
        return recording_limits(unknown)

    def _job(self, output: ReplayOutput | None = None, scratch: str | None = None) -> ConvertJob:
        opts = self.options
        return ConvertJob(path=self.path, obs_mode=opts.obs_mode, control_mode=opts.control_mode,
                          env_kwargs=opts.env_kwargs(), tolerances=self.tolerances, sim_backend=opts.sim_backend,
                          imports=tuple(opts.imports), trust_imports=opts.trust_recorded_imports,
                          converter=opts.converter, keep=tuple(opts.keep),
                          output=output, scratch=scratch, block_rows=opts.block_rows, scenes=self._scenes)

    @functools.cached_property
    def _scenes(self) -> dict[int, ScenePlace]:
        """`ConvertJob.scenes` of this conversion."""
        listed = {m.index: m for m in self.reader.episodes}
        if self.options.control_mode:
            return run_scenes([listed[i] for i in self.indices], str(Path(self.output).resolve()), self._recording_id)
        path = str(Path(self.path).resolve())
        scenes = {i: self._chains.copied_scene(i, path, self.reader.meta.recording_id) for i in self.indices}
        return {i: scene for i, scene in scenes.items() if scene is not None}

    @functools.cached_property
    def _chains(self) -> SceneChains:
        """The input's scene chains, found once for the re-render's scenes (`_scenes`) and this process's worker."""
        return SceneChains(self.reader.episodes)

    @functools.cached_property
    def _recording_id(self) -> str:
        """The output's `RecordingMeta.recording_id`, which a control-mode conversion's scenes name (`_scenes`)."""
        return new_recording_id()

    def _output_spec(self, worker: ConvertWorker, staged: Path) -> ReplayOutput:
        """The output as it is written: at `staged` in the run's scratch folder, moved to its name once checked."""
        poses = tuple(self.reader.meta.pose_bodies)  # a re-render's recorded ones, a control-mode conversion's own
        changes = {**worker.output_changes(), "provenance": self._provenance(), "recording_id": self._recording_id}
        return ReplayOutput(str(staged), pose_bodies=poses, command=self.options.command, changes=changes)

    def _conversion(self) -> dict[str, Any]:
        opts, meta = self.options, self.reader.meta
        changed = {}
        if opts.obs_mode is not None:
            changed["obs_mode"] = [meta.obs_mode, opts.obs_mode]
        if opts.control_mode is not None:
            changed["control_mode"] = [meta.control_mode, opts.control_mode]
        checked = checked_text(meta.unknown, tracked=bool(opts.control_mode),
                                obs=compares_obs(meta, opts.obs_mode, opts.env_kwargs()))
        return {**changed, **opts.env_kwargs(), "checked": checked}

    def _provenance(self) -> dict[str, Any]:
        opts = self.options
        return {"operation": "convert", "source": str(Path(self.path).resolve()),
                "source_recording_id": self.reader.meta.recording_id, "source_kind": self.reader.kind,
                "source_episodes": list(self.indices), "conversion": self._conversion(),
                "tolerances": self.tolerances.to_json(), "filters": {"episodes": self._named(), "count": opts.count,
                                                                     "keep": list(opts.keep)}}

    def _named(self) -> list[int] | None:
        """The episodes --episodes named, as the provenance lists them (None: all): as many as the file has at most,
        since `_indices` refused any it lacks."""
        return None if self.options.episodes is None else list(self.options.episodes)

    def execute(self, progress: Callable[[EpisodeReport], None] | None = None) -> ConversionReport:
        """Convert every episode, calling `progress` with each one's report as it finishes; closes the input. The
        output is written in the run's scratch folder (`ScratchFolder`, removed when the run ends, however it ends),
        read back and checked there, and only then moved to its name (`publish_checked`): a file that fails its
        check is never published, and an old output it was to replace stays as it was (`OutputCheckError`)."""
        meta = self.reader.meta
        report = ConversionReport(path=self.path, output=self.output, env_id=meta.env_id,
                                  conversion=self._conversion(), tolerances=self.tolerances.to_json(),
                                  limits=self._limits(meta))
        with ScratchFolder(self.output) as scratch:
            staged = staged_path(scratch)
            digests = self._convert(report, staged, scratch, progress)
            _check_written(self.path, staged, report, digests, states_too=self.options.control_mode is None)
            if report.written_mismatch:
                raise OutputCheckError(f"{self.output}: {report.written_check}; nothing was written to {self.output}")
            if report.written:
                publish_checked(staged, self.output, meta, overwrite=self.options.overwrite)
        return report

    def _convert(self, report: ConversionReport, staged: Path, scratch: ScratchFolder,
                 progress: Callable[[EpisodeReport], None] | None) -> dict[int, dict[str, str]]:
        """Convert every episode into `report` and the recording `staged` (complete and closed on return, or removed
        when nothing is written); returns each written episode's arrays' digests, to check it against."""
        chains = None if self.options.control_mode else self._chains  # a re-render's, found for `_scenes`
        worker = ConvertWorker(self._job(), self.reader, chains)  # closes the reader
        try:
            said = [f"{self.path}: {note}" for note in self.reader.notes]  # as a copy says them: groups not converted
            report.warnings = said + _fingerprint_warnings(worker) + self._one_process_note()
            spec = self._output_spec(worker, staged)
            with published(ReplayedWriter(spec, self.reader.meta, list(self.indices)),
                           keep=lambda: bool(report.written), final=self.output) as writer:
                worker.output = writer
                collector = _Collector(report, writer, progress)
                self._run(worker, spec, collector, scratch)
        finally:
            worker.close()
        order = {i: k for k, i in enumerate(self.indices)}
        report.episodes.sort(key=lambda e: order[e.index])
        report.written.sort(key=order.__getitem__)  # the input's order, as the output has them, however workers finished
        return collector.digests

    def _one_process_note(self) -> list[str]:
        """Why a control-mode conversion asked for several workers runs in one process: each converted episode is a
        new trajectory, stepped from its reset; an exact replay of the output steps it after the output's episodes
        before it, in one scene, so the conversion must have stepped them so too. Empty where nothing changes."""
        workers = min(self.options.workers, len(self.indices))
        return [_ONE_PROCESS.format(workers=workers)] if self.options.control_mode and workers > 1 else []

    def _run(self, worker: ConvertWorker, spec: ReplayOutput, collect: Callable[[ConvertResult], None],
             scratch: ScratchFolder) -> None:
        """Convert every episode here, or here and in `workers - 1` pool processes, which write each re-rendered
        episode to the run's scratch folder."""
        workers = 1 if self._one_process_note() else min(self.options.workers, len(self.indices))
        items = [WorkItem(key=self.reader.meta.env_id, path=self.path, index=i) for i in self.indices]
        if workers == 1:
            for item in items:
                collect(worker.run(item))
            return
        worker.job = self._job(spec, str(scratch.path))
        run_pool(worker, items, workers, collect)


_ONE_PROCESS = ("converted in one process, not {workers}: a control-mode conversion steps each episode after the "
                "ones before it in one scene, as a replay of the output will (PhysX results depend on the scene's "
                "history: `simreel.verdicts.scene_history`)")


def _fingerprint_warnings(worker: ConvertWorker) -> list[str]:
    from simreel.replay.run.fingerprint import fingerprint_differences

    return fingerprint_differences(worker.meta, worker.replayer.u)


class _Collector:
    """Takes each episode's result: its report into the run's report, and to the writer the episode (whole, in a
    scratch recording, or already written as it was converted) unless `keep` left it out."""

    def __init__(self, report: ConversionReport, writer: ReplayedWriter,
                 progress: Callable[[EpisodeReport], None] | None) -> None:
        self.report, self.writer, self.progress = report, writer, progress
        self.digests: dict[int, dict[str, str]] = {}
        """Episode -> its arrays' digests as handed to the writer (checked when read back)."""

    def __call__(self, result: ConvertResult) -> None:
        raise_if_stopped()  # a Ctrl-C that landed in a finalizer was printed and dropped by Python
        if result.error is not None:  # an episode that cannot be read, an env that does not build here
            raise result.error
        episode_report = result.report
        index = episode_report.index
        self.report.episodes.append(episode_report)
        if result.left_out:
            self.report.dropped[index] = result.left_out
            self.writer.put(index, None)
        else:
            self.report.written.append(index)
            self.digests[index] = result.digests
            self.writer.put(index, result.episode if result.episode is not None else result.scratch)
        if self.progress is not None:
            self.progress(episode_report)


def _check_written(src: str, written: Path, report: ConversionReport, digests: Mapping[int, dict[str, str]], *,
                   states_too: bool) -> None:
    """Read every episode of the recording `written` back (the output before it is published), a block at a time:
    its arrays must be byte for byte those that were written (`digests`), and for a re-render its states and
    actions those of the input. Those that are not go to `report.written_mismatch`."""
    if not report.written:
        report.written_check = "nothing written"
        return
    with open_reader(src) as source, open_reader(written) as out:
        for index in sorted(report.written):
            written = field_digests(out.open_episode(index))
            same = written == digests[index]
            if same and states_too:
                same = _states_and_actions(field_digests(source.open_episode(index))) == _states_and_actions(written)
            if not same:
                report.written_mismatch.append(index)
    report.written_check = (f"every written episode read back byte-identical to the {'re-rendered' if states_too else 'converted'} "
                            "one" + ("; its states and actions equal the input's exactly" if states_too else ""))
    if report.written_mismatch:
        report.written_check = (f"episodes {report.written_mismatch} do not read back as they were written"
                                + (" (or their states and actions are not the input's)" if states_too else ""))


def _states_and_actions(digests: Mapping[str, str]) -> dict[str, str]:
    """The digests of an episode's states and actions, of all its `field_digests`."""
    return {k: d for k, d in digests.items() if k.startswith("env_states/") or k == "actions"}
