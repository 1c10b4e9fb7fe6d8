"""How a worker gives an episode's scene the history it had when recorded, before replaying it
(`simreel.verdicts.scene_history` holds the rule, `simreel.replay.run.history` the records and their words): in mode
``actions`` the episodes that ran before it in the recorder's scene, which the worker's scene has not run (or only
the last step of the one right before, `_last_step`), on a rebuilt scene when it ran anything else; in the modes
that restore states, only the step before its reset.

`HistoryReplay` is a part of `simreel.replay.run.workers.ReplayWorker` (a base class of it): it works on the
worker's job and the scene chains of the file it replays last."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from simreel.errors import EPISODE_DATA_ERRORS
from simreel.formats import EpisodeReader
from simreel.replay.run.engine import RESTORING_MODES, EpisodeReplayer
from simreel.replay.run.history import (
    SHIPPED_HISTORY,
    ReplayedHistory,
    SceneRun,
    describe_missing_history,
    describe_missing_step_before,
    describe_unreadable_history,
    has_history,
    last_step_history,
    restoring_history,
    span,
    step_before,
)
from simreel.replay.run.sinks import BlockSink
from simreel.replay.run.worklist import WorkItem
from simreel.verdicts.scene_history import SceneChains

if TYPE_CHECKING:
    from simreel.replay.run.job import ReplayJob

__all__ = ["HistoryReplay"]


class HistoryReplay:
    """The history replayed before each episode (`ReplayWorker`'s; see the module)."""

    job: ReplayJob
    _chains: tuple[str, SceneChains] | None

    def _replay_history(self, reader: EpisodeReader, replayer: EpisodeReplayer, item: WorkItem,
                        scene: SceneRun | None, *, shipped: bool) -> ReplayedHistory:
        """In mode ``actions``, give `replayer`'s scene (which ran `scene`) the history episode `item.index` had
        when recorded (`simreel.verdicts.scene_history.SceneChains`). Where it lacks more than one predecessor, only the
        last step of the one right before is replayed, from its recorded state, on a rebuilt scene (`_last_step`):
        a reset keeps of the scene's history what that step leaves, and the episode is kept if it then replays
        exact; `run` replays the whole history where it does not. Else the predecessors it lacks are replayed
        (actions only, nothing compared or written), after rebuilding the scene when it ran anything else. The other
        modes restore recorded states: no history is replayed, only the step before the reset (`_step_before`).
        Where the history cannot be replayed (a `shipped` episode comes without its file; a predecessor's data is
        damaged) the episode is replayed on a rebuilt scene without it, and its report says so."""
        if self.job.mode in RESTORING_MODES:
            return self._step_before(reader, replayer, item, scene, shipped=shipped)
        episode = reader.episode_meta(item.index)
        if shipped:
            replayer.forget_scene()  # a rebuilt scene at least: the same replay on every actor
            return ReplayedHistory(lost=SHIPPED_HISTORY if has_history(episode) else None)
        chains = self._chains_of(item.path, reader)
        if not chains.complete(item.index):
            replayer.forget_scene()
            lost = describe_missing_history(episode, chains.ran_before[item.index], reader.meta.recording_id)
            return ReplayedHistory(lost=lost)
        done = scene.ran_of(item.path, chains, item.index) if scene is not None else None
        missing = chains.history(item.index, since=done or 0)
        if len(missing) > 1:
            fresh = scene is not None and not scene.ran  # (fresh from gym.make: no rebuild needed)
            short = self._last_step(reader, replayer, chains, item.index, fresh=fresh)
            if short is not None:
                return short
        elif not missing and scene is not None and scene.short:  # (its scene's history was a last step too)
            return ReplayedHistory(short=True)
        return self._replay_missing(reader, replayer, chains, item, done)

    def _last_step(self, reader: EpisodeReader, replayer: EpisodeReplayer, chains: SceneChains,
                   index: int, *, fresh: bool) -> ReplayedHistory | None:
        """The history of episode `index` as the last step of the episode right before it (`step_before`), re-run on a
        rebuilt scene (unless `fresh`: one that ran nothing since it was built) from its recorded state before the
        episode's reset; None where that step cannot be had."""
        found = step_before(reader, chains, index, None)
        if found.run is None or found.run.episode is None:
            return None
        if not fresh:
            replayer.forget_scene()
        why = last_step_history(found.run.episode.index, chains.ran_before[index] or 0)
        return ReplayedHistory(before=found.run, steps=1, why=why, short=True)

    def _whole_history(self, reader: EpisodeReader, replayer: EpisodeReplayer, item: WorkItem,
                       why: str) -> ReplayedHistory:
        """Episode `item.index`'s whole history, replayed on a rebuilt scene (`why`: for its report)."""
        history = self._replay_missing(reader, replayer, self._chains_of(item.path, reader), item, None)
        return dataclasses.replace(history, why=history.lost or why)

    def _replay_missing(self, reader: EpisodeReader, replayer: EpisodeReplayer, chains: SceneChains, item: WorkItem,
                        done: int | None) -> ReplayedHistory:
        """Replay the predecessors of `item` from place `done` on (None: its whole history, on a rebuilt scene)."""
        missing = chains.history(item.index, since=done or 0)
        if done is None and not (missing or [reader.episode_meta(item.index)])[0].reconfigured:
            replayer.forget_scene()  # (a chain whose first reset rebuilt the scene rebuilds it itself)
        for ep in missing:
            try:
                replayer.replay_rows(reader.open_episode(ep.index), BlockSink(), mode="actions",
                                     rows=self.job.block_rows)
            except EPISODE_DATA_ERRORS as e:
                replayer.forget_scene()  # the episode itself then starts from a rebuilt scene, with no history
                return ReplayedHistory(lost=describe_unreadable_history(ep.index, e))
        if not missing:
            return ReplayedHistory()
        replayed = [ep.index for ep in missing]
        return ReplayedHistory(replayed, [ep.index for ep in chains.history(item.index)],
                               steps=sum(ep.length for ep in missing),
                               why=f"episode(s) {span(replayed)}, which its scene had not run")

    def _previous(self, reader: EpisodeReader, item: WorkItem) -> int:
        previous = self._chains_of(item.path, reader).previous(item.index)
        return previous.index if previous is not None else item.index - 1

    def _step_before(self, reader: EpisodeReader, replayer: EpisodeReplayer, item: WorkItem, scene: SceneRun | None,
                     *, shipped: bool) -> ReplayedHistory:
        """In a restoring mode, the step `item`'s recorder's scene ran before its reset, for the observations there
        (`simreel.replay.run.history.step_before`): none to re-run when no observation is replayed or the scene ran it last."""
        if not replayer.need_obs:
            return ReplayedHistory()
        if shipped:
            return ReplayedHistory(lost=describe_missing_step_before("sent without its file"))
        return restoring_history(reader, self._chains_of(item.path, reader), item, scene)

    def _chains_of(self, path: str, reader: EpisodeReader) -> SceneChains:
        """The chains of the file at `path` (`SceneChains`), found once per file the worker meets in a row."""
        if self._chains is None or self._chains[0] != path:
            self._chains = (path, SceneChains(reader.episodes))
        return self._chains[1]
