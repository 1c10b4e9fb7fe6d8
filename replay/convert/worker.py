"""Where a conversion's episodes are converted and checked: a `ConvertWorker` (one reader and the envs that convert
its episodes) in this process, and one in each worker process of a pool (`simreel.replay.run.pool.run_pool`). A
re-render restores each recorded state and renders its observations (mode ``states``); a control-mode conversion
steps the converted actions and measures how well they track the recorded ones (`simreel.replay.convert.tracking`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from simreel.errors import SimreelError
from simreel.formats import EpisodeReader, open_reader
from simreel.model.lineage import EpisodeProvenance, ScenePlace
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.replay.convert.job import ConvertJob, ConvertResult, states_tolerances
from simreel.replay.convert.replayer import ConvertingReplayer
from simreel.replay.convert.sinks import RenderedRows, TrackingSink, WrittenEpisode
from simreel.replay.convert.tracking import Commands
from simreel.replay.report.report import EpisodeReport
from simreel.replay.run.history import ReplayedHistory, SceneRun, restoring_history
from simreel.replay.run.output import EpisodeStream, ReplayedWriter, ScratchEpisode
from simreel.replay.run.replayer_options import ReplayerOptions
from simreel.replay.run.sinks import Collected, VerifySink
from simreel.replay.run.worklist import WorkItem
from simreel.sim.user_code import resolve_task_imports
from simreel.verdicts.compare import CompareScope
from simreel.verdicts.scene_history import SceneChains

__all__ = ["ConvertWorker", "compares_obs"]


class ConvertWorker:
    """One reader and the envs that convert its episodes: the replayer (target modes) and, for a control-mode
    conversion, a state-only env in the recorded control mode whose controller splits recorded actions."""

    def __init__(self, job: ConvertJob, reader: EpisodeReader | None = None, chains: SceneChains | None = None) -> None:
        self.job = job
        self.reader = reader if reader is not None else open_reader(job.path)
        self.source_env: Any = None
        self.output: ReplayedWriter | None = None
        """The output when this process writes it: a re-rendered episode next in its order is written as it is
        re-rendered."""
        self._chains = chains
        """The input's scene chains (`SceneChains`): given by a run that found them already, else found when needed."""
        self._scene: SceneRun | None = SceneRun()
        """What the re-rendering scene ran last (`ReplayWorker`'s rule; None: unknown)."""
        try:
            meta = self.reader.meta
            self.meta = dataclasses.replace(meta, imports=resolve_task_imports(meta.imports, explicit=job.imports,
                                                                               recording=job.path,
                                                                               trust=job.trust_imports))
            self.replayer = ConvertingReplayer(self.meta, self._replayer_options())
            self.converter = self._converter() if job.control_mode else None
        except BaseException:
            self.close()
            raise

    def _replayer_options(self) -> ReplayerOptions:
        """The replayer's modes; a control-mode conversion also samples the recorded bodies' poses of its own run
        (a re-render writes the recorded ones: its states are the recorded ones)."""
        job = self.job
        need_obs = job.obs_mode is not None or bool(self.meta.obs_layout)
        poses = tuple(self.meta.pose_bodies) if job.control_mode else ()
        return ReplayerOptions(obs_mode=job.obs_mode or (self.meta.obs_mode if need_obs else None), need_obs=need_obs,
                               control_mode=job.control_mode, env_kwargs=dict(job.env_kwargs),
                               sim_backend=job.sim_backend, pose_bodies=poses)

    def _converter(self) -> Any:
        from simreel.replay.convert.control import converter_for
        from simreel.sim.rebuild import build_with_render_fallback, env_from_meta

        def build(render: str) -> Any:
            return env_from_meta(self.meta, num_envs=1, obs_mode="none", render_backend=render,
                                 **({"sim_backend": self.job.sim_backend} if self.job.sim_backend else {}))

        self.source_env = build_with_render_fallback(build, "none")[0]
        make = self.job.converter or converter_for
        return make(self.meta.control_mode, self.job.control_mode, self.replayer.u, self.source_env.unwrapped.agent.controller)

    def output_changes(self) -> dict[str, Any]:
        """The output's metadata fields that this conversion changes."""
        from simreel.sim.describe import action_space_json
        from simreel.sim.fingerprint import with_controllers

        u = self.replayer.u
        return {"obs_mode": self.replayer.obs_mode if self.replayer.need_obs else self.meta.obs_mode,
                "control_mode": u.control_mode,
                "action_space": action_space_json(self.meta.env_id, u.single_action_space),
                "env_kwargs": {**self.meta.env_kwargs, **self.job.env_kwargs},
                "scene_fingerprint": with_controllers(self.meta.scene_fingerprint, u),
                **self._layout_change(u)}

    def _layout_change(self, unwrapped: Any) -> dict[str, Any]:
        """The output's state layout when its controller keeps state the input's lacks (a target mode's target)."""
        from simreel.sim.state import live_layout

        if self.job.control_mode is None or not self.meta.state_layout:
            return {}
        live = live_layout(unwrapped)
        return {"state_layout": live} if set(live) != set(self.meta.state_layout) else {}

    def run(self, item: WorkItem) -> ConvertResult:
        """Convert and check episode `item.index` of this worker's file; a `SimreelError` comes back in the result."""
        try:
            return self._convert_actions(item) if self.converter is not None else self._render(item)
        except SimreelError as e:
            return ConvertResult(item, error=e)

    def _convert_actions(self, item: WorkItem) -> ConvertResult:
        """Convert episode `item.index`'s actions a block of rows at a time: each recorded block's actions are
        converted and stepped, the run's tracking errors taken (`TrackingSink`) and its rows written as they come."""
        source = self.reader.open_episode(item.index)
        stream = self._stream(source.meta)
        written = WrittenEpisode(stream or Collected())
        tracked = TrackingSink(self.replayer, self.job.tolerances, source.meta.initial_state_known, written)
        try:
            run = self.replayer.replay_converted_rows(source, self.converter, tracked, rows=self.job.block_rows)
            commands = None if run.commands is None else Commands(run.commands, tuple(run.clipped))
            cmp = tracked.blocks.comparison(commands)
            report = EpisodeReport.from_comparison(source, cmp, notes=run.notes, limits=run.limits,
                                                   seconds=run.seconds)
            report.checked = _tracked(list(cmp.errors))
            report.per_step = {k: [float(x) for x in e] for k, e in cmp.errors.items()}
        except BaseException:
            written.discard()
            raise
        meta = dataclasses.replace(source.meta, initial_state_known=True)
        meta = _provenance_meta(meta, report, self.job.scenes.get(item.index), clipped=len(run.clipped))
        return written.finish(item, report, meta, source.length, self.job.keep)

    def _render(self, item: WorkItem) -> ConvertResult:
        """Re-render episode `item.index` a block of rows at a time: each recorded block's states are restored and
        checked, its observations rendered, and the output's rows (`RenderedRows`) written as they come."""
        source = self.reader.open_episode(item.index)
        stream = self._stream(source.meta)
        written = WrittenEpisode(stream or Collected())
        scope = CompareScope(initial=source.meta.initial_state_known,
                             obs=compares_obs(self.meta, self.job.obs_mode, self.job.env_kwargs))
        verify = VerifySink(states_tolerances(), self.meta.contact_channels, scope, RenderedRows(written))
        history = self._step_before(item)
        try:
            self.replayer.rerun_step_before(history.before)
            run = self.replayer.replay_rows(source, verify, mode="states", rows=self.job.block_rows)
            report = EpisodeReport.from_comparison(source, verify.comparison(), notes=run.notes, limits=run.limits,
                                                   seconds=run.seconds)
        except BaseException:
            written.discard()
            raise
        history.tell(report, item.index)
        self._scene = SceneRun.after(self.job.path, self._chains, item.index)
        meta = _provenance_meta(source.meta, report, self.job.scenes.get(item.index))
        return written.finish(item, report, meta, source.length, self.job.keep)

    def _step_before(self, item: WorkItem) -> ReplayedHistory:
        """The step before `item`'s reset, which its observations there read (`restoring_history`); the
        re-rendering scene's last step is unknown until its replay ends well."""
        if self._chains is None:
            self._chains = SceneChains(self.reader.episodes)
        scene, self._scene = self._scene, None
        if not self.replayer.need_obs:
            return ReplayedHistory()
        return restoring_history(self.reader, self._chains, item, scene)

    def _stream(self, episode: EpisodeMeta) -> EpisodeStream | None:
        """Where the conversion of `episode` is written as it comes: into the output when this process writes it and
        the episode is next; else into a scratch recording of its own (given a scratch folder); else nowhere (None:
        it is collected whole)."""
        stream = self.output.stream(episode) if self.output is not None else None
        if stream is None and self.job.scratch is not None and self.job.output is not None:
            stream = ScratchEpisode(Path(self.job.scratch), self.job.output, self.reader.meta, episode)
        return stream

    def close(self) -> None:
        for closing in (getattr(self, "replayer", None), self.source_env, self.reader):
            if closing is not None:
                closing.close()


def compares_obs(meta: RecordingMeta, obs_mode: str | None, env_kwargs: Mapping[str, Any]) -> bool:
    """Whether a re-render into `obs_mode` (with camera options `env_kwargs`) compares the observations it renders
    with those of the recording `meta` describes: the recording holds some in that mode, of no camera (images of
    another render device differ, and are not the trajectory)."""
    from simreel.sim.make import camera_use

    return (bool(meta.obs_layout) and obs_mode == meta.obs_mode and not env_kwargs
            and camera_use(obs_mode) is None)


def _tracked(keys: list[str]) -> list[str]:
    groups = {"command": "commanded pose", "ee": "end-effector pose", "env_states": "object poses",
              "success": "success"}
    return [name for prefix, name in groups.items() if any(k.split("/", 1)[0].split("[", 1)[0] == prefix for k in keys)]


def _provenance_meta(meta: EpisodeMeta, report: EpisodeReport, scene: ScenePlace | None, *,
                     clipped: int | None = None) -> EpisodeMeta:
    """The converted episode's metadata: `meta` with the conversion's verdict and where it ran (`scene`,
    `ConvertJob.scenes`) as its provenance."""
    first = None if report.first_divergence is None else report.first_divergence.to_json()
    provenance = EpisodeProvenance(
        source_episode=report.index, verdict=report.verdict, checked=tuple(report.checked), first_exceeded=first,
        max_error={k: float(v) if np.isfinite(v) else str(v) for k, v in report.max_abs_error.items()},
        clipped_steps=clipped, scene=scene)
    return dataclasses.replace(meta, notes=[], provenance=provenance)
