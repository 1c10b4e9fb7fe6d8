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

__all__ = ["scene_history", "chain_starts", "SceneChains", "describe_history"]


def chain_starts(episodes: Sequence[EpisodeMeta]) -> dict[int, int]:
    """Episode index → index of the episode that starts its chain: the episodes that ran one after another in one
    scene since it was built. A chain starts at a sub-scene's (``env_idx``) first episode (the recorder's env was
    fresh) and at each episode whose reset rebuilt the scene (``reconfigured`` True); ``reconfigured`` None
    (unknown: ManiSkill's files) is taken as not rebuilt: replaying a predecessor too many costs time, one too few
    gives a wrong verdict. One pass over the episodes in index order."""
    starts: dict[int, int] = {}
    current: dict[int, int] = {}
    for ep in sorted(episodes, key=lambda e: e.index):
        if ep.reconfigured or ep.env_idx not in current:
            current[ep.env_idx] = ep.index
        starts[ep.index] = current[ep.env_idx]
    return starts


class SceneChains:
    """The chains of one recording's episodes (`chain_starts`), found once: each episode's chain and place in it, so
    that a worker finds an episode's history without walking the whole episode list again (a file may hold tens of
    thousands of episodes in one chain)."""

    def __init__(self, episodes: Sequence[EpisodeMeta]) -> None:
        self.start = chain_starts(episodes)
        """Episode index → the index of the episode that starts its chain."""
        self.members: dict[int, list[EpisodeMeta]] = {}
        """Chain start → its episodes, first to last."""
        for ep in sorted(episodes, key=lambda e: e.index):
            self.members.setdefault(self.start[ep.index], []).append(ep)
        self.position = {ep.index: k for chain in self.members.values() for k, ep in enumerate(chain)}
        """Episode index → how many episodes of its chain ran before it."""

    def history(self, index: int) -> list[EpisodeMeta]:
        """The episodes that ran in episode `index`'s scene before it since the scene was built, first to last."""
        return self.members[self.start[index]][: self.position[index]]


def scene_history(episodes: Sequence[EpisodeMeta], index: int) -> list[EpisodeMeta]:
    """The episodes of `episodes` (a recording's episode list) that ran in episode `index`'s scene before it since
    that scene was built, first to last: those of its chain (`chain_starts`) recorded before it. An episode whose
    own reset rebuilt the scene has none. `KeyError` when `index` is not listed."""
    return SceneChains(episodes).history(index)


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
