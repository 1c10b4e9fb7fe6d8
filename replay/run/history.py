"""The scene history an episode is replayed after (`simreel.verdicts.scene_history` holds the rule): what a worker's
scene ran (`SceneRun`), how an episode's scene was given its history (`ReplayedHistory`), what a report says about it
(`describe_history` and the rest), and, for a replay that restores recorded states, the step before its reset.

The step before an episode's reset, in a replay that restores recorded states (`RESTORING_MODES`): PhysX reports the contacts of the last step its scene simulated until it simulates another, and a reset simulates
nothing: observations taken at a reset read the contacts of the step before it. ManiSkill's ``is_grasping``, in
many tasks' observations, is 1 at the reset after a grasping episode (measured: SimreelLiftCube-v1, whose state
replay of such an episode alone rendered 0 there, and diverged). When recorded, that step was the last step of the
episode that ran before it in its scene (`simreel.verdicts.scene_history.SceneChains.previous`), or none (a scene just built).
A restoring replay re-runs it (`SceneBefore`), so that the observations it compares or writes at a reset do not
depend on which episode its process happened to replay before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from simreel.errors import EPISODE_DATA_ERRORS, RecordingFileError
from simreel.formats import EpisodeReader
from simreel.model.fields import field_group
from simreel.model.meta import EpisodeMeta
from simreel.replay.report.report import EpisodeReport, HistoryEntry
from simreel.replay.run.resets import SceneBefore
from simreel.replay.run.worklist import WorkItem
from simreel.verdicts.scene_history import SceneChains, recorded_scene

__all__ = ["describe_history", "last_step_history", "whole_history_after", "describe_missing_history", "describe_missing_step_before", "describe_unreadable_history",
           "SHIPPED_HISTORY", "span", "SceneRun", "ReplayedHistory", "restoring_history", "has_history", "StepBefore",
           "step_before"]

_MAY_DIVERGE = "PhysX results depend on the scene's history: a divergence may come from that alone"
SHIPPED_HISTORY = ("replayed without the episodes that ran before it in the recorder's scene (sent without its file); "
                   + _MAY_DIVERGE)
"""The limit of an episode shipped to a Ray actor, whose history is not replayed."""


def describe_history(index: int, history: Sequence[int], replayed: Sequence[int]) -> str:
    """The note of episode `index`, replayed after its recorded predecessors `history`, of which `replayed` were
    replayed just for that (actions only: not verified)."""
    return (f"episode {index} replayed after its recorded predecessor(s) {span(history)} (PhysX results depend on "
            f"the scene's history); {span(replayed)} replayed for that, not verified")


def last_step_history(previous: int, predecessors: int) -> str:
    """Why a replay ran only the last step of episode `previous` (one of `predecessors`) before an episode."""
    return (f"only the last step of episode {previous}, from its recorded state, on a scene just built, in place of its "
            f"{predecessors} predecessor(s): PhysX results depend on the scene's history, and the episode replayed "
            "exact after that step alone (else its whole history would have been replayed)")


def whole_history_after(previous: int, verdict: str, first: str | None) -> str:
    """Why a replay ran an episode's whole history after trying only the last step of episode `previous`, after
    which the episode replayed `verdict` (`first`: where it first differed)."""
    where = f" ({first})" if first else ""
    return (f"its whole history: replayed after only the last step of episode {previous} (from its recorded state), "
            f"it was {verdict}{where}, not exact")


def describe_missing_history(episode: EpisodeMeta, ran_before: int | None, recording_id: str) -> str:
    """The limit of `episode`, a copy or a recorded episode whose file (whose `RecordingMeta.recording_id` is
    `recording_id`) does not hold the `ran_before` episodes (None: an unknown number) that ran in its scene before it
    when it was recorded: it is replayed on a rebuilt scene without them."""
    scene = recorded_scene(episode)
    if scene is not None and recording_id and scene.recording == recording_id:
        return (f"replayed on a rebuilt scene without the {ran_before} episode(s) that ran in its scene before it when "
                f"this file's conversion stepped them (from episode {scene.start}): the conversion left some of "
                f"them out of this file (--keep, or a failed episode); {_MAY_DIVERGE}")
    if scene is None and episode.origin is None and episode.chain is not None:
        return (f"replayed on a rebuilt scene without the {ran_before} episode(s) that ran in its scene before it when "
                f"it was recorded (from episode {episode.chain.start}): this file does not hold them all (left out "
                f"of a copy, or damaged and lost by recover); {_MAY_DIVERGE}")
    if scene is None:
        return ("replayed on a rebuilt scene: made from another recording (copied, converted or replayed) by a simreel "
                f"that did not note which episodes ran in its scene before it when it was recorded; {_MAY_DIVERGE}")
    return (f"replayed on a rebuilt scene without the {ran_before} episode(s) that ran in its scene before it when "
            f"it was recorded ({Path(scene.file).name}, from episode {scene.start}): this file, made from "
            f"another by simreel filter, merge or convert, does not hold them all; {_MAY_DIVERGE}")


def describe_unreadable_history(index: int, error: Exception) -> str:
    """The limit of an episode whose predecessor `index` could not be replayed (`error`)."""
    return (f"replayed without the episodes that ran before it in the recorder's scene: episode {index} cannot be "
            f"read ({error}); {_MAY_DIVERGE}")


def describe_missing_step_before(why: str) -> str:
    """The limit of an episode whose restoring replay could not re-run the step before its reset
    (`step_before`), for `why`."""
    return (f"its observations at the reset read the contacts of whatever step its replaying scene ran last, not of "
            f"the one its recorder's scene ran before it ({why}): contact-based values there (is_grasped) may differ")


def span(indices: Sequence[int]) -> str:
    """``0–4`` for consecutive episode indices, else ``0, 2, 5``."""
    if len(indices) > 1 and list(indices) == list(range(indices[0], indices[-1] + 1)):
        return f"{indices[0]}–{indices[-1]}"
    return ", ".join(map(str, indices))


@dataclass(frozen=True)
class SceneRun:
    """What a worker's scene ran since it was built: the first `ran` episodes (places 0 to `ran` - 1) of chain
    `chain` of the file at `path` (`simreel.verdicts.scene_history.SceneChains`); ``SceneRun()``: nothing, a scene fresh
    from ``gym.make`` or rebuilt. In a restoring mode, only its last step counts: that of the one at place `ran` - 1
    (`step_before`)."""

    path: str | None = None
    chain: str | None = None
    ran: int = 0
    short: bool = False
    """Its history was only the last step of one episode (`last_step_history`): the next episode of the chain is then
    kept only if it replays exact, else replayed again after its whole history."""

    @classmethod
    def after(cls, path: str, chains: SceneChains, index: int, *, short: bool = False) -> SceneRun:
        """The scene that ran episode `index` of the file at `path` last, after its history (`short`: only the last
        step of its predecessor)."""
        return cls(path, chains.key[index], (chains.ran_before[index] or 0) + 1, short)

    def ran_of(self, path: str, chains: SceneChains, index: int) -> int | None:
        """How many episodes of episode `index`'s history (in the file at `path`) this scene has run already; None
        when it ran something else (another file, chain or episode): it must be rebuilt first."""
        if not self.ran:
            return 0
        same = self.path == path and self.chain == chains.key[index]
        return self.ran if same and self.ran <= (chains.ran_before[index] or 0) else None


@dataclass
class ReplayedHistory:
    """How a worker gave an episode's scene its recorded history (`ReplayWorker._replay_history`)."""

    replayed: list[int] = field(default_factory=list)
    """The predecessors replayed for it just now (the scene had run the others)."""
    ran: list[int] = field(default_factory=list)
    """Its whole history, which the scene has now run (listed where some of it was `replayed`, for the note)."""
    lost: str | None = None
    """Why its history could not be replayed (it is then replayed without), for its report's limits; in a restoring
    mode, why the step before its reset could not be re-run."""
    before: SceneBefore | None = None
    """The step before its reset, which its replay re-runs first (`step_before`): in a restoring mode; in mode
    ``actions`` where only that step is replayed of its history (`short`)."""
    steps: int = 0
    """The predecessors' steps replayed for it just now."""
    why: str = ""
    """Why that much (`HistoryEntry.why`; empty: the scene had run its history, or it has none)."""
    short: bool = False
    """Mode ``actions``: only the last step of the episode before is replayed (`before`) on a rebuilt scene, or the
    scene's history came from such a step; the replay is kept only if it is exact."""

    def tell(self, report: EpisodeReport, index: int) -> None:
        """Add to episode `index`'s `report` what was replayed before it, or what could not be."""
        if self.replayed:
            report.notes.append(describe_history(index, self.ran, self.replayed))
        if self.lost:
            report.notes.append(self.lost)
            report.limits.append(self.lost)

    def entry(self, first_of_scene: bool) -> HistoryEntry:
        """The report's `HistoryEntry` of an actions replay (`first_of_scene`: the episode's scene was just built when
        recorded)."""
        episodes = 1 if self.short and self.before is not None else len(self.replayed)
        why = self.why or self.lost or ("the first episode of its scene" if first_of_scene else
                                        "its scene had just run its predecessors (replayed before it in this run)")
        return HistoryEntry(episodes, self.steps, why)


def restoring_history(reader: EpisodeReader, chains: SceneChains, item: WorkItem,
                      scene: SceneRun | None) -> ReplayedHistory:
    """What a restoring replay of `item` (of `reader`'s file, whose chains are `chains`) runs before it, on a scene
    that ran `scene` (None: unknown): the step before its reset (`step_before`), or why it cannot."""
    ran = scene.ran_of(item.path, chains, item.index) if scene is not None else None
    found = step_before(reader, chains, item.index, ran)
    return ReplayedHistory(lost=found.lost, before=found.run)


def has_history(episode: EpisodeMeta) -> bool:
    """Whether episodes may have run in `episode`'s scene before it (told by its metadata alone: where a copy says
    where it ran, that; else whether its reset kept the scene and it is not its file's first)."""
    scene = recorded_scene(episode)
    if scene is not None:
        return scene.position > 0
    return not episode.reconfigured and episode.index > 0


class StepBefore(NamedTuple):
    """What a restoring replay of an episode re-runs before its reset (`SceneBefore`; None: nothing, the scene's
    last step is that one already), and why it cannot (`lost`, for the report's limits; `run` is then None)."""

    run: SceneBefore | None
    lost: str | None = None


def step_before(reader: EpisodeReader, chains: SceneChains, index: int, ran: int | None) -> StepBefore:
    """The step episode `index` of `reader`'s file (whose chains are `chains`) had before its reset when recorded.
    `ran`: how many episodes of its chain the replaying scene ran, the last of them last (`SceneRun.ran_of`; None:
    unknown): when that is the one before it, nothing is re-run."""
    place = chains.ran_before[index]
    unknown = _unknown_place(reader, place)
    if unknown:
        return StepBefore(None, describe_missing_step_before(unknown))
    if place == ran:
        return StepBefore(None)
    previous = chains.previous(index)
    while previous is not None and not previous.length:  # an episode of no step simulated nothing
        place = chains.ran_before[previous.index]
        previous = chains.previous(previous.index)
    if not place:
        return StepBefore(SceneBefore())
    if previous is None:
        return StepBefore(None, describe_missing_step_before("the episode that ran before it is not in this file"))
    try:
        return StepBefore(_last_step(reader, previous))
    except EPISODE_DATA_ERRORS as e:
        return StepBefore(None, describe_missing_step_before(f"episode {previous.index} ran before it: {e}"))


def _unknown_place(reader: EpisodeReader, place: int | None) -> str | None:
    """Why the place of an episode of `reader`'s file in its chain (`place`) is unknown, if it is: a copy that does
    not say, or a file of parallel envs that does not say which one ran each episode (ManiSkill's)."""
    if place is None:
        return "where it ran when recorded is unknown"
    if reader.meta.num_envs > 1 and "env_idx" in reader.meta.unknown:
        return "the file does not say which of its parallel envs ran each episode"
    return None


def _last_step(reader: EpisodeReader, episode: EpisodeMeta) -> SceneBefore:
    """`episode`'s last step: the state row before it, and its action (`RecordingFileError` if it holds NaN, or the
    state before is not in the file: the row 0 of an episode whose `initial_state_known` is False)."""
    rows, length = reader.open_episode(episode.index), episode.length
    action = rows.steps(length - 1, length)["actions"][0]
    if np.isnan(action).any():
        raise RecordingFileError(reader.path, f"the last action of episode {episode.index} holds NaN")
    if length == 1 and not episode.initial_state_known:
        raise RecordingFileError(reader.path, f"the state before the one step of episode {episode.index} is not in "
                                              "the file (its row 0 is the state after it)")
    before = rows.reset() if length == 1 else rows.steps(length - 2, length - 1)
    state = {path: a[-1:] for path, a in field_group(before.arrays, "env_states").items()}
    return SceneBefore(rows.meta, state, action, length - 1)
