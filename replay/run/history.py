"""What a replay report says about an episode's scene history (`simreel.verdicts.scene_history`, the rule): which predecessors
were replayed before it, and why its history could not be.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from simreel.model.meta import EpisodeMeta
from simreel.verdicts.scene_history import recorded_scene

__all__ = ["describe_history", "describe_missing_history", "describe_missing_step_before", "describe_unreadable_history",
           "SHIPPED_HISTORY"]

_MAY_DIVERGE = "PhysX results depend on the scene's history: a divergence may come from that alone"
SHIPPED_HISTORY = ("replayed without the episodes that ran before it in the recorder's scene (sent without its file); "
                   + _MAY_DIVERGE)
"""The limit of an episode shipped to a Ray actor, whose history is not replayed."""


def describe_history(index: int, history: Sequence[int], replayed: Sequence[int]) -> str:
    """The note of episode `index`, replayed after its recorded predecessors `history`, of which `replayed` were
    replayed just for that (actions only: not verified)."""
    return (f"episode {index} replayed after its recorded predecessor(s) {_span(history)} (PhysX results depend on "
            f"the scene's history); {_span(replayed)} replayed for that, not verified")


def describe_missing_history(episode: EpisodeMeta, ran_before: int | None, recording_id: str) -> str:
    """The limit of `episode`, a copy or a recorded episode whose file (whose `RecordingMeta.recording_id` is
    `recording_id`) does not hold the `ran_before` episodes (None: an unknown number) that ran in its scene before it
    when it was recorded: it is replayed on a rebuilt scene without them."""
    scene = recorded_scene(episode)
    if scene is not None and recording_id and scene.get("recording") == recording_id:
        return (f"replayed on a rebuilt scene without the {ran_before} episode(s) that ran in its scene before it when "
                f"this file's conversion stepped them (from episode {scene['start']}): the conversion left some of "
                f"them out of this file (--keep, or a failed episode); {_MAY_DIVERGE}")
    if scene is None and not episode.origin and episode.chain:
        return (f"replayed on a rebuilt scene without the {ran_before} episode(s) that ran in its scene before it when "
                f"it was recorded (from episode {episode.chain['start']}): this file does not hold them all (left out "
                f"of a copy, or damaged and lost by recover); {_MAY_DIVERGE}")
    if scene is None:
        return ("replayed on a rebuilt scene: made from another recording (copied, converted or replayed) by a simreel "
                f"that did not note which episodes ran in its scene before it when it was recorded; {_MAY_DIVERGE}")
    return (f"replayed on a rebuilt scene without the {ran_before} episode(s) that ran in its scene before it when "
            f"it was recorded ({Path(scene['file']).name}, from episode {scene['start']}): this file, made from "
            f"another by simreel filter, merge or convert, does not hold them all; {_MAY_DIVERGE}")


def describe_unreadable_history(index: int, error: Exception) -> str:
    """The limit of an episode whose predecessor `index` could not be replayed (`error`)."""
    return (f"replayed without the episodes that ran before it in the recorder's scene: episode {index} cannot be "
            f"read ({error}); {_MAY_DIVERGE}")


def describe_missing_step_before(why: str) -> str:
    """The limit of an episode whose restoring replay could not re-run the step before its reset
    (`simreel.replay.run.last_step`), for `why`."""
    return (f"its observations at the reset read the contacts of whatever step its replaying scene ran last, not of "
            f"the one its recorder's scene ran before it ({why}): contact-based values there (is_grasped) may differ")


def _span(indices: Sequence[int]) -> str:
    """``0–4`` for consecutive episode indices, else ``0, 2, 5``."""
    if len(indices) > 1 and list(indices) == list(range(indices[0], indices[-1] + 1)):
        return f"{indices[0]}–{indices[-1]}"
    return ", ".join(map(str, indices))
