"""Where episodes are replayed: a `ReplayWorker` (readers and one rebuilt env) in this process, and one in each
worker process of a pool (`run_pool`), each replaying episodes of any file of the run, a block of rows at a time,
and answering with an `EpisodeResult`.

A worker keeps the env it built for the last env key (`simreel.replay.run.worklist.env_key`) and rebuilds only when
the key changes; the work list is ordered by key so that is rare. In mode ``actions`` it also keeps what its env's
scene ran since it was built (`SceneRun`), and before an episode replays the episodes that ran before it in the
recorder's scene (`simreel.verdicts.scene_history`) which its scene has not run, rebuilding the scene first when it ran
anything else (`simreel.replay.run.history_replay`): PhysX's CPU results depend on that history. A `ReplayJob` is everything a worker needs,
picklable so that worker processes (`simreel.replay.run.pool`) and Ray actors (`simreel.replay.run.ray_pool`) can
build their own.
"""

from __future__ import annotations

import dataclasses
import os
import socket
from pathlib import Path

from simreel.errors import SimreelError
from simreel.formats import EpisodeReader
from simreel.formats.base import EpisodeRows
from simreel.model.episode import Episode
from simreel.model.lineage import EpisodeProvenance, ScenePlace
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.replay.explain.explain import ExplainContext, explain_divergence
from simreel.replay.report.report import EpisodeReport
from simreel.replay.run.engine import RESTORING_MODES, EpisodeReplayer, ReplayedEpisode
from simreel.replay.run.history import ReplayedHistory, SceneRun, whole_history_after
from simreel.replay.run.history_replay import HistoryReplay
from simreel.replay.run.job import EpisodeResult, ReplayJob
from simreel.replay.run.output import (
    EpisodeStream,
    RecordedContacts,
    ReplayedWriter,
    ReplayOutput,
    ScratchEpisode,
    output_pose_bodies,
)
from simreel.replay.run.readers import ReaderCache
from simreel.replay.run.sinks import BlockSink, Collected, VerifySink
from simreel.replay.run.worklist import WorkItem
from simreel.verdicts.compare import CompareScope
from simreel.verdicts.scene_history import SceneChains

__all__ = ["ReplayWorker"]


class ReplayWorker(HistoryReplay):
    """Replays work items of any file of a run: one process's readers and its one env (per env key)."""

    def __init__(self, job: ReplayJob) -> None:
        self.job = job
        self._readers = ReaderCache()
        self._key: str | None = None
        self._replayer: EpisodeReplayer | None = None
        self._failed: dict[str, SimreelError] = {}
        """Env keys whose env could not be built, with why: their other episodes fail at once, the same way."""
        self._warned: set[str] = set()
        self._scene: SceneRun | None = None
        """What the env's scene ran since it was built (None: unknown, e.g. after a failed or explained replay)."""
        self._chains: tuple[str, SceneChains] | None = None
        """The episode chains of the file last replayed (`_chains_of`)."""
        self.output: ReplayedWriter | None = None
        """The `-o` output when this process writes it: the episode next in its order is written as it is replayed."""
        self.where = f"{socket.gethostname()} pid {os.getpid()}"
        """Which process replays: what each result names as its worker."""

    def run(self, item: WorkItem, shipped: EpisodeReader | None = None) -> EpisodeResult:
        """Replay and verify `item`, read from its file or from `shipped` (the episode, sent where the file is not);
        a `SimreelError` comes back in the result, never raised."""
        where = self.where
        try:
            reader = shipped if shipped is not None else self._readers.get(item.path)
            replayer = self._replayer_for(item, reader.meta)
            scene, self._scene = self._scene, None  # unknown until the replay ends well
            history = self._replay_history(reader, replayer, item, scene, shipped=shipped is not None)
            report, replayed = self._replay(reader, replayer, item.index, history, self._ran_in(item, reader, history))
            if report.verdict != "exact" and history.short:  # the short history was not enough: the whole one
                history = self._whole_history(reader, replayer, item, whole_history_after(
                    self._previous(reader, item), report.verdict, _first(report)))
                report, replayed = self._replay(reader, replayer, item.index, history,
                                                self._ran_in(item, reader, history))
        except SimreelError as e:
            return EpisodeResult(item, error=e, worker=where)
        restoring = self.job.mode in RESTORING_MODES  # (what it ran last counts, not what ran before it)
        if not restoring:
            report.history = history.entry(shipped is None and not self._chains_of(item.path, reader).ran_before.get(
                item.index, 1))
        if report.explanation is None and shipped is None and (restoring or history.lost is None):
            chains = self._chains_of(item.path, reader)  # (an explanation steps again; a lost history ran none)
            self._scene = SceneRun.after(item.path, chains, item.index, short=history.short)
        episode, scratch = (None, replayed) if isinstance(replayed, Path) else (replayed, None)
        return EpisodeResult(item, report, episode, scratch=scratch, worker=where, history=history.replayed,
                             warnings=self._warnings(item.path, reader, replayer))

    def prepare(self, item: WorkItem) -> None:
        """Open `item`'s file and build its env now; raises the `SimreelError` that stops that."""
        self._replayer_for(item, self._readers.get(item.path).meta)

    def _replayer_for(self, item: WorkItem, meta: RecordingMeta) -> EpisodeReplayer:
        key = item.key
        if key in self._failed:
            raise self._failed[key]
        if key != self._key or self._replayer is None:
            self._close_replayer()
            try:
                meta = self.job.meta_for(meta, item.path)
                self._replayer = EpisodeReplayer(meta, self.job.replayer_options(meta))
            except SimreelError as e:
                self._failed[key] = e
                raise
            self._key, self._scene = key, SceneRun()
        return self._replayer

    def _ran_in(self, item: WorkItem, reader: EpisodeReader, history: ReplayedHistory) -> ScenePlace | None:
        """For `-o`, where the replay of `item` ran (``provenance["scene"]`` of the replayed episode,
        `simreel.verdicts.scene_history`): in an actions replay after its recorded history, the recorded episode's scene;
        without it (a rebuilt scene), a chain of its own in the output. None: not written, or states restored."""
        if self.job.output is None or self.job.mode != "actions":
            return None
        if history.lost is not None:
            return ScenePlace(str(Path(self.job.output).resolve()), item.index, 0)
        chains = self._chains_of(item.path, reader)
        return chains.copied_scene(item.index, str(Path(item.path).resolve()), reader.meta.recording_id)

    def _replay(self, reader: EpisodeReader, replayer: EpisodeReplayer, index: int, history: ReplayedHistory,
                ran_in: ScenePlace | None = None) -> tuple[EpisodeReport, Episode | Path | None]:
        """Replay episode `index` block by block, comparing each block as it is replayed (and, for `-o`, writing it
        where `_stream` says); only the per-key error curves outlive a block. `history`: how its scene's history was
        replayed just before (`_replay_history`), which its report notes. Returns the report and, for `-o`, the scratch
        recording the replay went to, or (no scratch folder) the replay collected whole."""
        job = self.job
        source = reader.open_episode(index)
        scope = CompareScope(initial=source.meta.initial_state_known,
                             obs=job.obs_mode is None or job.obs_mode == reader.meta.obs_mode)
        stream = self._stream(reader.meta, source.meta, direct=not history.short)
        kept = Collected() if job.output is not None and stream is None else None
        written: BlockSink | None = stream or kept
        if written is not None and job.mode == "states":
            written = RecordedContacts(written)
        verify = VerifySink(job.tolerances, reader.meta.contact_channels, scope, written)
        verify.explain = not history.short
        try:
            replayer.rerun_step_before(history.before)
            replayed = replayer.replay_rows(source, verify, mode=job.mode, resync=job.resync, rows=job.block_rows)
            report = self._report(reader, replayer, source, replayed, verify)
            history.tell(report, index)
        except BaseException:
            if stream is not None:
                stream.discard()
            raise
        if history.short and report.verdict != "exact":  # `run` replays it again, after its whole history
            if stream is not None:
                stream.discard()
            return report, None
        if stream is not None:
            stream.commit(_replayed_meta(source.meta, report, ran_in), source.length)
        if kept is None:
            return report, stream.path if isinstance(stream, ScratchEpisode) else None
        episode = kept.episode(source.meta)
        return report, dataclasses.replace(episode, meta=_replayed_meta(episode.meta, report, ran_in))

    def _stream(self, meta: RecordingMeta, episode: EpisodeMeta, *, direct: bool = True) -> EpisodeStream | None:
        """Where the replay of `episode` (of the recording with `meta`) is written as it comes: into `-o` when this
        process writes it, the episode is next and the replay is no attempt that may be dropped (`direct`: an output
        never takes an episode index twice); else, given a scratch folder, into a scratch recording of its own; else
        nowhere (None: without `-o`, or collected whole)."""
        job = self.job
        stream = self.output.stream(episode) if self.output and direct else None
        if stream is None and job.output is not None and job.scratch is not None:
            spec = ReplayOutput(job.output, obs_mode=job.obs_mode, pose_bodies=output_pose_bodies(meta, job.output))
            stream = ScratchEpisode(Path(job.scratch), spec, meta, episode)
        return stream

    def _report(self, reader: EpisodeReader, replayer: EpisodeReplayer, source: EpisodeRows,
                replayed: ReplayedEpisode, verify: VerifySink) -> EpisodeReport:
        """The report of `source`'s replay, judged by `verify`, explained where it diverged (not when it is only an
        attempt after a short history, `ReplayedHistory.short`, which `run` replays again unless exact)."""
        meta = reader.meta
        cmp = verify.comparison()
        report = EpisodeReport.from_comparison(source, cmp, notes=replayed.notes, limits=replayed.limits,
                                               seconds=replayed.seconds)
        report.scene_differences = replayed.scene_differences
        if cmp.first_divergence is not None and verify.explain:  # after the report's timing: explaining steps again
            from simreel.replay.run.fingerprint import fingerprint_differences

            ctx = ExplainContext(mode=self.job.mode, resync=self.job.resync, channels=list(meta.contact_channels),
                                 env_id=meta.env_id, build_differences=fingerprint_differences(meta, replayer.u))
            # the recorded episode again, without its observations (camera frames), for the explanation's replays
            recorded = source.episode(obs=False)
            report.explanation = explain_divergence(replayer, recorded, replayed, cmp, ctx)
        return report

    def _warnings(self, path: str, reader: EpisodeReader, replayer: EpisodeReplayer) -> list[str]:
        """What to say once of the file `path`: what its reader noticed (e.g. groups a ManiSkill sidecar does not
        list, which are not replayed) and where its build differs from this machine's."""
        from simreel.replay.run.fingerprint import fingerprint_differences

        if path in self._warned:
            return []
        self._warned.add(path)
        return [*getattr(reader, "notes", []), *fingerprint_differences(reader.meta, replayer.u)]

    def _close_replayer(self) -> None:
        if self._replayer is not None:
            self._replayer.close()
            self._replayer, self._key, self._scene = None, None, None

    def close(self) -> None:
        self._close_replayer()
        self._readers.close()


def _replayed_meta(meta: EpisodeMeta, report: EpisodeReport, ran_in: ScenePlace | None) -> EpisodeMeta:
    """The metadata `-o` writes with a replayed episode: the recorded one's, with the replay's verdict and where the
    replay ran (`ReplayWorker._ran_in`)."""
    provenance = meta.provenance
    if ran_in is not None:
        provenance = dataclasses.replace(provenance or EpisodeProvenance(), scene=ran_in)
    return dataclasses.replace(meta, verification=report.verification(), provenance=provenance)



def _first(report: EpisodeReport) -> str | None:
    """Where `report`'s replay first differed from its recording, in words (None: nowhere past its tolerance)."""
    return report.first_divergence.describe() if report.first_divergence is not None else None
