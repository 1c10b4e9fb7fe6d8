"""Convert a recording to another observation mode and/or control mode, and prove each episode is still the
same trajectory: what `simreel convert IN OUT --obs-mode ... --control-mode ...` runs.

- **Observation mode** only (re-rendering, e.g. ``rgb``, ``pointcloud``): every recorded state is restored and the
  observations are computed from it (`EpisodeReplayer`, mode ``states``). The output keeps the input's states,
  actions, rewards and flags as they are (it adds only what the input lacks: rewards, success, fail recomputed
  from the states); the check: each restored state reads back within the ``states`` tolerances (a restore
  changes a state by <= 1.5e-8), the recomputed rewards and flags agree, and so do the recorded contact forces
  with those of one step simulated from the state (``states`` mode's 20 N); after writing, the output's states
  and actions are read back and must equal the input's exactly.
- **Control mode** (with or without a new observation mode): each recorded action is converted one step for
  one (`simreel.replay.convert.control`) and the converted actions are stepped from the episode's reset; the resulting
  trajectory is compared with the recorded one at every step (`simreel.replay.convert.tracking`: tool-centre pose,
  object poses, success timing), each episode getting its largest tracking errors, the first step one leaves
  its tolerance, and a verdict.

Filters: `episodes`, `count` (the first N of those are converted), `keep` (which of the converted episodes are
written: ``verified`` ones by default, also ``success``/``not_truncated`` ones if asked, or ``all``). The output's metadata says where it came from (`RecordingMeta.provenance`: source file,
episodes, the conversion, the tolerances) and each episode's verdict (`EpisodeMeta.provenance`). Episodes run in
this process and ``workers - 1`` more (`simreel.replay.run.workers.run_pool`).

Both read, convert, check and write an episode a block of rows at a time (the camera frames of a long episode never
sit in memory whole): into the output when the episode is next in its order, else into a scratch recording of its
own (`simreel.replay.run.output.ScratchEpisode`), copied in at its turn. What outlives a block is per-row errors, a
control-mode conversion's commanded poses and success flags (a few dozen bytes a step). The output is written in
the run's scratch folder, and every written episode read back from there a block at a time, its arrays' digests
compared with those of what was written (`simreel.datasets.digests.FieldHashes`), before the output is moved to its
name: one that fails the check is never published (`OutputCheckError`), and an old file it was to replace stays.
"""

from __future__ import annotations

import dataclasses
import functools
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simreel.datasets.digests import FieldHashes, field_digests
from simreel.errors import OutputCheckError, SimreelError, UsageError
from simreel.formats import EpisodeReader, check_writable, format_of, open_reader, recording_files
from simreel.io.durable import raise_if_stopped
from simreel.io.targets import check_distinct
from simreel.model.blocks import StepBlock
from simreel.model.components import Tolerances, format_number
from simreel.model.lineage import ScenePlace
from simreel.model.meta import EpisodeMeta, RecordingMeta, new_recording_id
from simreel.options.checks import (
    options_with,
)
from simreel.replay.convert.control import check_pair
from simreel.replay.convert.options import KEEP, ConvertOptions
from simreel.replay.convert.replayer import ConvertingReplayer
from simreel.replay.convert.tracking import Commands, EndEffector, TrackingBlocks, tracking_tolerances
from simreel.replay.report.report import (
    CHECK_ORDER,
    WITH_ENV_STATES,
    EpisodeReport,
    episode_lines,
    recording_limits,
)
from simreel.replay.run.engine import GPU_SIM_BACKENDS, BlockSink, Collected, EpisodeReplayer, ReplayerOptions
from simreel.replay.run.output import (
    EpisodeStream,
    ReplayedWriter,
    ReplayOutput,
    ScratchEpisode,
    ScratchFolder,
    publish_checked,
    published,
    staged_path,
)
from simreel.replay.run.workers import (
    EpisodeResult,
    ReplayedHistory,
    SceneRun,
    VerifySink,
    restoring_history,
    run_pool,
)
from simreel.replay.run.worklist import WorkItem
from simreel.sim.user_code import refuse_untrusted_imports, resolve_task_imports
from simreel.verdicts.compare import CompareScope
from simreel.verdicts.scene_history import SceneChains, run_scenes

__all__ = ["KEEP", "ConvertOptions", "ConvertJob", "ConvertWorker", "ConversionReport", "ConversionRun",
           "convert_recording"]

_TRACKING_LIMITS = ("versions", "sim_config", "scene_seeds", "reset_options", "env_idx", "success")
"""What a file may not hold that limits a control-mode conversion's check (`RecordingMeta.unknown`)."""


@dataclass(frozen=True)
class ConvertJob:
    """What every worker of one conversion does (picklable: worker processes build their own workers)."""

    path: str
    obs_mode: str | None
    control_mode: str | None
    env_kwargs: dict[str, Any]
    tolerances: Tolerances
    sim_backend: str | None = None
    imports: tuple[str, ...] = ()
    trust_imports: bool = False
    """``--trust-recorded-imports``: the input's recorded imports may be imported (`resolve_task_imports`)."""
    converter: Callable[..., Any] | None = None
    keep: tuple[str, ...] = ("verified",)
    output: ReplayOutput | None = None
    """The output's spec (path, metadata changes): what a scratch episode is written as."""
    scratch: str | None = None
    """The run's scratch folder (`ScratchFolder`), where a worker writes an episode that is not next in the output's
    order; None: such an episode comes back whole."""
    block_rows: int | None = None
    scenes: dict[int, ScenePlace] = field(default_factory=dict)
    """Episode index → where its conversion ran, kept in its provenance (``"scene"``, `simreel.verdicts.scene_history`): a
    re-rendered episode is the recorded trajectory, so its scene is the input's; a control-mode conversion steps the
    episodes one after another in one env, so it ran in that run."""

    def open_worker(self) -> ConvertWorker:
        """The worker a pool process converts episodes in (`run_pool` calls it in each process)."""
        return ConvertWorker(self)


def _states_tolerances() -> Tolerances:
    return Tolerances.for_mode("states")


@dataclass
class ConvertResult(EpisodeResult):
    """What converting one episode gave (`EpisodeResult`: its report, and the converted episode whole, or the scratch
    recording holding it, or neither: it was written as it was converted), and what the worker decided: why `keep`
    leaves it out ("": it is written) and, when written, its arrays' `FieldHashes` digests, to check the output
    against."""

    left_out: str = ""
    digests: dict[str, str] = field(default_factory=dict)


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
        converted and stepped, the run's tracking errors taken (`_Tracked`) and its rows written as they come."""
        source = self.reader.open_episode(item.index)
        stream = self._stream(source.meta)
        written = _Written(stream or Collected())
        tracked = _Tracked(self.replayer, self.job.tolerances, source.meta.initial_state_known, written)
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
        checked, its observations rendered, and the output's rows (`_Rendered`) written as they come."""
        source = self.reader.open_episode(item.index)
        stream = self._stream(source.meta)
        written = _Written(stream or Collected())
        scope = CompareScope(initial=source.meta.initial_state_known,
                             obs=_compares_obs(self.meta, self.job.obs_mode, self.job.env_kwargs))
        verify = VerifySink(_states_tolerances(), self.meta.contact_channels, scope, _Rendered(written))
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


_RENDER_CHECKS = {"env_states": "each restored state read back within the 'states' tolerances",
                  "obs": "the rendered observations against the recorded ones",
                  "contacts": "recorded contact forces against one step simulated from the state",
                  "info": "recorded info", "rewards": "recomputed rewards"}
"""What a re-render compares of each group (`CHECK_ORDER`; the flags, `_FLAGS`, as one) when the file holds it."""
_FLAGS = ("terminated", "truncated", "success", "fail")


def _checked_text(unknown: list[str], *, tracked: bool, obs: bool) -> str:
    """What a conversion compares per step of a file that does not hold `unknown` (`RecordingMeta.unknown`, which
    also gives the limits lines): a re-render what a replay in mode 'states' compares of what the file holds (its
    observations where `obs`, `_compares_obs`), a control-mode conversion the tracking groups (success timing when
    the file holds success)."""
    if tracked:
        groups = ["commanded and reached tool-centre pose", "object poses", "success timing"]
        groups = groups if "success" not in unknown else groups[:-1]
        return "per step, the converted run against the recorded one: " + ", ".join(groups)
    held = [g for g in CHECK_ORDER if (g != "obs" or obs) and g not in unknown]
    flags = [g for g in held if g in _FLAGS]
    parts = [_RENDER_CHECKS[g] for g in held if g not in _FLAGS] + [f"recomputed flags ({', '.join(flags)})"]
    return "per step, " + ", ".join(parts) + "; the output's states and actions equal the input's"


def _compares_obs(meta: RecordingMeta, obs_mode: str | None, env_kwargs: Mapping[str, Any]) -> bool:
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


class _Written(BlockSink):
    """Hands each converted block on to `then` (an `EpisodeStream` into the output or a scratch recording, or a
    `Collected` episode), hashing it (`hashes`) for the check of what is written and noting (success, truncated) at
    the last step so far (`last`), for `keep`; `finish` then commits the episode or leaves it out."""

    def __init__(self, then: EpisodeStream | Collected) -> None:
        self.then = then
        self.start()

    def start(self) -> None:
        self.hashes = FieldHashes()
        self.last: tuple[bool | None, bool | None] = (None, None)
        self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.hashes.add(replayed, replayed.arrays)
        self.then.reset(recorded, replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.hashes.add(replayed, replayed.arrays)
        if replayed.rows:
            self.last = _last_flags(replayed.get("success"), replayed["truncated"])
        self.then.steps(first, recorded, replayed)

    def discard(self) -> None:
        """Drop what was written of the episode (an error or Ctrl-C stopped its conversion)."""
        if isinstance(self.then, EpisodeStream):
            self.then.discard()

    def finish(self, item: WorkItem, report: EpisodeReport, meta: EpisodeMeta, length: int,
               keep: tuple[str, ...]) -> ConvertResult:
        """The episode's result: left out by `keep` (what was written of it discarded), or committed with `meta`
        (the scratch recording's path with it), or collected whole."""
        why = _left_out(report, self.last, keep)
        if why:
            self.discard()
            return ConvertResult(item, report, left_out=why)
        digests = self.hashes.digests()
        if isinstance(self.then, Collected):
            return ConvertResult(item, report, self.then.episode(meta), digests=digests)
        self.then.commit(meta, length)
        scratch = self.then.path if isinstance(self.then, ScratchEpisode) else None
        return ConvertResult(item, report, scratch=scratch, digests=digests)


class _Rendered(BlockSink):
    """The output rows of a re-render as they are replayed, handed on to `then`: the recorded rows as they are,
    with the replay's observations in place of the recorded ones, and the rewards and flags the recording lacks
    taken from the replay (recomputed from the restored states)."""

    _FILLED = ("rewards", "success", "fail")

    def __init__(self, then: BlockSink) -> None:
        self.then = then

    def start(self) -> None:
        self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.then.reset(recorded, self._output(recorded, replayed, ()))

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.then.steps(first, recorded, self._output(recorded, replayed, self._FILLED))

    @staticmethod
    def _output(recorded: StepBlock, replayed: StepBlock, filled: tuple[str, ...]) -> StepBlock:
        arrays = {k: a for k, a in recorded.arrays.items() if not k.startswith("obs/")}
        arrays.update({k: a for k, a in replayed.arrays.items()
                       if k.startswith("obs/") or (k in filled and k not in arrays)})
        return StepBlock(arrays, recorded.rows)


class _Tracked(BlockSink):
    """Takes the tracking errors of each block of a control-mode conversion (`TrackingBlocks`, bound to the
    replayer's end effector when the episode's replay starts, after its reset) and hands the block on to `then`."""

    def __init__(self, replayer: EpisodeReplayer, tolerances: Tolerances, initial: bool, then: BlockSink) -> None:
        self._args = (replayer, tolerances, initial)
        self.then = then

    def start(self) -> None:
        replayer, tolerances, initial = self._args
        self.blocks = TrackingBlocks(EndEffector(replayer.u), tolerances, initial=initial)
        self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.reset(recorded, replayed)
        self.then.reset(recorded, replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.steps(recorded, replayed)
        self.then.steps(first, recorded, replayed)


def _last_flags(success: np.ndarray | None, truncated: np.ndarray) -> tuple[bool | None, bool | None]:
    """(success, truncated) at the last of these steps; None where there is no step (or no success flag)."""
    if not len(truncated):
        return None, None
    return (None if success is None else bool(success[-1])), bool(truncated[-1])


def _provenance_meta(meta: EpisodeMeta, report: EpisodeReport, scene: ScenePlace | None, *,
                     clipped: int | None = None) -> EpisodeMeta:
    """The converted episode's metadata: `meta` with the conversion's verdict and where it ran (`scene`,
    `ConvertJob.scenes`) as its provenance."""
    meta = dataclasses.replace(meta, notes=[])
    meta.provenance = {
        "source_episode": report.index,
        "verdict": report.verdict,
        "checked": list(report.checked),
        "first_exceeded": None if report.first_divergence is None else report.first_divergence.to_json(),
        "max_error": {k: float(v) if np.isfinite(v) else str(v) for k, v in report.max_abs_error.items()},
        **({"clipped_steps": clipped} if clipped is not None else {}),
        **({"scene": scene.to_json()} if scene is not None else {}),
    }
    return meta


# ------------------------------------------------------------------------------------------------ the report
@dataclass
class ConversionReport:
    """Every episode of one conversion: its verdict, whether it was written, and the check of the written file."""

    path: str
    output: str
    env_id: str
    conversion: dict[str, Any]
    tolerances: dict[str, float]
    episodes: list[EpisodeReport] = field(default_factory=list)
    written: list[int] = field(default_factory=list)
    dropped: dict[int, str] = field(default_factory=dict)
    """Episode -> why a `keep` filter left it out."""
    written_check: str = ""
    written_mismatch: list[int] = field(default_factory=list)
    """Written episodes whose states or actions read back from the output differ from what they must be."""
    warnings: list[str] = field(default_factory=list)
    limits: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every converted episode verified (written or left out), something written, and the written file
        checked."""
        return bool(self.written) and all(e.ok for e in self.episodes) and not self.written_mismatch

    def to_json(self) -> dict[str, Any]:
        return {"ok": self.ok, "path": self.path, "output": self.output, "env_id": self.env_id,
                "conversion": self.conversion, "tolerances": self.tolerances, "warnings": self.warnings,
                "limits": self.limits, "written": self.written, "left_out": len(self.dropped), "dropped": {str(k): v for k, v in self.dropped.items()},
                "written_check": self.written_check, "written_mismatch": self.written_mismatch,
                "episodes": [e.to_json() for e in self.episodes]}

    def summary(self) -> str:
        """The table `simreel convert` prints."""
        steps = sum(e.length for e in self.episodes)
        tracked = bool(self.conversion.get("control_mode"))
        lines = [f"conversion of {self.path} -> {self.output}: {self.env_id}, {describe(self.conversion)}, "
                 f"{len(self.episodes)} episode(s), {steps} steps"]
        if tracked:
            lines.append("  largest error per episode: commanded and reached tool-centre pose (m, rad), objects (m, "
                         "rad), success timing (steps); tolerances "
                         + ", ".join(f"{k} {format_number(v)}" for k, v in self.tolerances.items()))
        head = f"  {'episode':>7} {'steps':>6}  {'verdict':<17}"
        columns = ("cmd m", "cmd rad", "ee m", "ee rad", "obj m", "obj rad")
        lines.append(head + ("".join(f" {c:>8}" for c in columns) + f" {'succ':>4}" if tracked else "")
                     + " first step out of tolerance")
        for e in self.episodes:
            rows = episode_lines(e)
            if tracked:
                rows[0] = _tracked_row(e)
            lines += rows
            if e.index in self.dropped:
                lines.append(f"  {'':>7} {'':>6}  {'':<17} not written: {self.dropped[e.index]}")
        lines += [f"limit: {limit}" for limit in self.limits]
        lines.append(f"checked: {self.conversion['checked']}")
        if self.written_check:
            lines.append(f"written: {self.written_check}")
        n_ok = sum(e.ok and e.index not in self.written_mismatch for e in self.episodes)
        lines.append(f"{n_ok} of {len(self.episodes)} episode(s) verified; {len(self.written)} written to {self.output}"
                     + self._left_out_text())
        return "\n".join(lines)

    def _left_out_text(self) -> str:
        """``; 3 left out (2 not verified, 1 no success at its last step)``: how many `keep` left out, and why."""
        if not self.dropped:
            return ""
        why = Counter(reason.split(" (")[0] for reason in self.dropped.values())
        hint = "; --keep all writes them" if "not verified" in why else ""
        return (f"; {len(self.dropped)} left out by --keep ({', '.join(f'{n} {w}' for w, n in why.items())}"
                f"{hint})")


def describe(conversion: Mapping[str, Any]) -> str:
    """``obs none -> rgb, control pd_joint_pos -> pd_ee_delta_pose``."""
    parts = [f"{what.split('_')[0]} {pair[0]} -> {pair[1]}" for what in ("obs_mode", "control_mode")
             if (pair := conversion.get(what))]
    return ", ".join(parts)


def _tracked_row(e: EpisodeReport) -> str:
    """An episode's row with its largest tracking error per group."""
    def worst(prefix: str, suffix: str) -> str:
        values = [v for k, v in e.max_abs_error.items() if k.startswith(prefix) and k.endswith(suffix)]
        return format_number(max(values)) if values else "-"

    success = e.max_abs_error.get("success")
    cells = [worst("command/", "[p]"), worst("command/", "[q]"), worst("ee/", "[p]"), worst("ee/", "[q]"),
             worst("env_states/", "p]"), worst("env_states/", "q]")]
    first = e.first_divergence.describe() if e.first_divergence else ""
    return (f"  {e.index:>7} {e.length:>6}  {e.verdict:<17} " + " ".join(f"{c:>8}" for c in cells)
            + f" {'-' if success is None else format_number(success):>4} {first}").rstrip()


# ------------------------------------------------------------------------------------------------ the run
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
                               else _states_tolerances())
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
        checked = _checked_text(meta.unknown, tracked=bool(opts.control_mode),
                                obs=_compares_obs(meta, opts.obs_mode, opts.env_kwargs()))
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


def _left_out(report: EpisodeReport, last: tuple[bool | None, bool | None], keep: tuple[str, ...]) -> str:
    """Why `keep` leaves the episode out ("" to write it), given (success, truncated) at its last step
    (`_last_flags`)."""
    success, truncated = last
    if "all" in keep:
        return ""
    if not report.ok:
        return f"not verified ({report.verdict})"
    if "success" in keep and not success:
        return "no success at its last step"
    if "not_truncated" in keep and truncated:
        return "truncated (time limit)"
    return ""


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


def convert_recording(src: str | Path, dst: str | Path, options: ConvertOptions | None = None, *,
                      progress: Callable[[EpisodeReport], None] | None = None, **overrides: Any) -> ConversionReport:
    """Convert the recording `src` into a new recording `dst`: `ConversionRun(src, dst, options,
    **overrides).execute(progress)`; `overrides` are `ConvertOptions` fields, e.g.
    ``convert_recording("demos.h5", "ee.h5", control_mode="pd_ee_delta_pose", keep=["verified"])``."""
    with ConversionRun(src, dst, options, **overrides) as run:
        return run.execute(progress)
