"""What a worker is given and what it gives back: a `ReplayJob` (everything a worker needs to replay an episode of
any file of the run: mode, tolerances, how to build the env; picklable, so that worker processes and Ray actors
build their own) and an `EpisodeResult` (the report of one work item, or the user error that stopped it)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from simreel.errors import EPISODE_DATA_ERRORS, SimreelError
from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.meta import RecordingMeta
from simreel.replay.report.report import EpisodeReport
from simreel.replay.run.output import output_pose_bodies
from simreel.replay.run.replayer_options import ReplayerOptions
from simreel.replay.run.worklist import WorkItem
from simreel.sim.user_code import resolve_task_imports

if TYPE_CHECKING:
    from simreel.replay.run.workers import ReplayWorker

__all__ = ["EpisodeResult", "ReplayJob"]


@dataclass(frozen=True)
class ReplayJob:
    """What every worker of one run does with an episode: mode, tolerances, and how to build the env."""

    mode: str
    resync: int | None
    tolerances: Tolerances
    obs_mode: str | None = None
    sim_backend: str | None = None
    output: str | None = None
    """Where the replayed episodes go (`-o`): workers then write them (or return them), with the bodies' poses it
    needs."""
    scratch: str | None = None
    """With `output`: the run's scratch folder (`simreel.replay.run.output.ScratchFolder`), where a worker writes, as
    it replays it, each episode it cannot write into the output itself (`ScratchEpisode`), and returns its path.
    None: such an episode is collected whole and returned (a Ray actor, which may not share this file system)."""
    imports: tuple[str, ...] = ()
    """`--import` specs given now: used instead of the recorded ones (`resolve_task_imports`)."""
    trust_imports: bool = False
    """``--trust-recorded-imports``: the recorded ones may be imported (`resolve_task_imports`)."""
    block_rows: int | None = None
    """Steps read, replayed and compared at a time (None: the reader's `simreel.formats.base.block_rows`)."""

    def replayer_options(self, meta: RecordingMeta) -> ReplayerOptions:
        """How to build the env replaying the recording with `meta`."""
        need_obs = bool(meta.obs_layout) or self.obs_mode is not None
        need_rewards = "rewards" not in meta.unknown or self.output is not None
        return ReplayerOptions(obs_mode=self.obs_mode, need_obs=need_obs, need_rewards=need_rewards,
                               sim_backend=self.sim_backend, pose_bodies=output_pose_bodies(meta, self.output))

    def meta_for(self, meta: RecordingMeta, path: str) -> RecordingMeta:
        """The metadata of the recording at `path` with its task's code found: the job's `--import`s, else the
        recorded ones, looked for where `resolve_task_imports` looks."""
        return dataclasses.replace(meta, imports=resolve_task_imports(meta.imports, explicit=self.imports,
                                                                      recording=path, trust=self.trust_imports))

    def open_worker(self) -> ReplayWorker:
        """The worker a pool process runs this job in (`run_pool` calls it in each process)."""
        from simreel.replay.run.workers import ReplayWorker

        return ReplayWorker(self)


@dataclass
class EpisodeResult:
    """What replaying one work item gave: its report (and for `-o` the scratch recording of the replay, or the
    replayed arrays), or the user error that stopped it (an unreadable episode, an env that does not build),
    which the caller reports or raises."""

    item: WorkItem
    report: EpisodeReport | None = None
    episode: Episode | None = None
    """The replayed episode, whole: only where the job has no scratch folder (Ray)."""
    scratch: Path | None = None
    """The scratch recording holding the replayed episode (`ReplayJob.scratch`), for `ReplayedWriter.put`."""
    history: list[int] = field(default_factory=list)
    """Episodes of the item's file replayed (actions only, not verified) before it, to give its scene the history
    it had when recorded (`simreel.verdicts.scene_history`); empty when the scene had it already."""
    warnings: list[str] = field(default_factory=list)
    """What differs between the recording's machine and this one (`simreel.replay.run.fingerprint`); given with the
    first result of each file a worker replays."""
    error: SimreelError | None = None
    worker: str = ""
    """Which process replayed it: host and pid (and Ray node)."""

    @property
    def env_error(self) -> bool:
        """The error is about the file's env, not this episode's data: the file's other episodes fail alike."""
        return self.error is not None and not isinstance(self.error, EPISODE_DATA_ERRORS)
