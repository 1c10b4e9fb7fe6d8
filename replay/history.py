"""Which episodes ran in an episode's scene before it: the history an actions replay must reproduce first.

PhysX's CPU results depend on the scene's history, not only on its state: an episode replayed from
``reset(seed)`` with its recorded actions gives the recorded numbers bit for bit only when the env's scene ran the
same episodes before it, since the scene was built, as it did while recording (measured: the last episode of a
grasp-and-lift recording, replayed on a fresh env, leaves the recording by 3 rad/s at step 9; replayed after its
predecessor, it is exact). Only the episodes since the scene was last built count: a reset that rebuilds the scene
(``reconfigure``) gives the state of a fresh env again.

`scene_history` is the one rule: `simreel.replay.workers.ReplayWorker` replays the predecessors it names (actions
only, nothing compared) before it replays an episode in mode ``actions``. The other modes restore recorded states
and have tolerances of their own; they do not replay histories.

Assumptions and known gaps:

- the recorder's env was fresh from ``gym.make`` when recording began (simreel's recorder and ManiSkill's
  RecordEpisode both wrap a new env), so a recording's first episode of each sub-scene starts a chain;
- episodes of one sub-scene (``env_idx``) ran in index order;
- a file written by ``simreel filter`` or ``merge`` holds episodes whose history may be in another file (or left
  out): its episodes are taken as recorded in it, which a replay may then find diverged; not solved here;
- an episode shipped alone to a Ray actor (``--ship``) comes without its file: its history cannot be replayed.
"""

from __future__ import annotations

from collections.abc import Sequence

from simreel.episode import EpisodeMeta

__all__ = ["scene_history", "describe_history"]


def scene_history(episodes: Sequence[EpisodeMeta], index: int) -> list[EpisodeMeta]:
    """The episodes of `episodes` (a recording's episode list) that ran in episode `index`'s scene before it since
    that scene was built, first to last: those of its sub-scene (``env_idx``) recorded before it, back to the
    nearest whose reset rebuilt the scene (``reconfigured`` True), which starts the chain and is included; without
    one, back to the sub-scene's first episode (the recorder's env was fresh). An episode whose own reset rebuilt
    the scene has none. ``reconfigured`` None (unknown: ManiSkill's files) is taken as not rebuilt: replaying a
    predecessor too many costs time, one too few gives a wrong verdict. `KeyError` when `index` is not listed."""
    by_index = {ep.index: ep for ep in episodes}
    episode = by_index[index]
    if episode.reconfigured:
        return []
    chain: list[EpisodeMeta] = []
    for ep in sorted(by_index.values(), key=lambda e: e.index, reverse=True):
        if ep.index >= index or ep.env_idx != episode.env_idx:
            continue
        chain.append(ep)
        if ep.reconfigured:
            break
    return chain[::-1]


def describe_history(index: int, history: Sequence[int], replayed: Sequence[int]) -> str:
    """The note of episode `index`, replayed after its recorded predecessors `history`, of which `replayed` were
    replayed just for that (actions only: not verified)."""
    return (f"episode {index} replayed after its recorded predecessor(s) {_span(history)} (PhysX results depend on "
            f"the scene's history); {_span(replayed)} replayed for that, not verified")


def _span(indices: Sequence[int]) -> str:
    """``0–4`` for consecutive episode indices, else ``0, 2, 5``."""
    if len(indices) > 1 and list(indices) == list(range(indices[0], indices[-1] + 1)):
        return f"{indices[0]}–{indices[-1]}"
    return ", ".join(map(str, indices))
