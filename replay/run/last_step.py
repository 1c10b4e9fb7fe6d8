"""The step before an episode's reset, for a replay that restores recorded states (`RESTORING_MODES`).

PhysX reports the contacts of the last step its scene simulated until it simulates another, and a reset simulates
nothing: observations taken at a reset read the contacts of the step before it. ManiSkill's ``is_grasping``, in
many tasks' observations, is 1 at the reset after a grasping episode (measured: SimreelLiftCube-v1, whose state
replay of such an episode alone rendered 0 there, and diverged). When recorded, that step was the last step of the
episode that ran before it in its scene (`simreel.verdicts.scene_history.SceneChains.previous`), or none (a scene just built).
A restoring replay re-runs it (`SceneBefore`), so that the observations it compares or writes at a reset do not
depend on which episode its process happened to replay before.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from simreel.errors import EPISODE_DATA_ERRORS, RecordingFileError
from simreel.formats import EpisodeReader
from simreel.model.fields import field_group
from simreel.model.meta import EpisodeMeta
from simreel.replay.run.engine import SceneBefore
from simreel.replay.run.history import describe_missing_step_before
from simreel.verdicts.scene_history import SceneChains

__all__ = ["StepBefore", "step_before"]


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
