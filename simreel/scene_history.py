"""Which episodes ran in an episode's scene before it: the history an actions replay must reproduce first.

PhysX's CPU results depend on the scene's history, not only on its state: an episode replayed from
``reset(seed)`` with its recorded actions gives the recorded numbers bit for bit only when the env's scene ran the
same episodes before it, since the scene was built, as it did while recording (measured: the last episode of a
grasp-and-lift recording, replayed on a fresh env, leaves the recording by 3 rad/s at step 9; replayed after its
predecessor, it is exact). Only the episodes since the scene was last built count: a reset that rebuilds the scene
(``reconfigure``) gives the state of a fresh env again.

`SceneChains` is the one rule. A recording's episodes form chains: those that ran one after another in one scene
since it was built. A chain starts at a sub-scene's (``env_idx``) first episode (the recorder's env was fresh:
simreel's recorder and ManiSkill's RecordEpisode both wrap a new env) and at each episode whose reset rebuilt the
scene (``reconfigured`` True; None, unknown as in ManiSkill's files, is taken as not rebuilt: replaying a
predecessor too many costs time, one too few gives a wrong verdict); episodes of one sub-scene ran in index order.

An episode copied by ``simreel filter`` or ``merge`` keeps where it ran (``EpisodeMeta.origin["scene"]``,
`SceneChains.copied_scene`): its recording, the index there of its chain's first episode and its place in that
chain. A file's copies of one recorded chain form a chain of that file, and an episode's history is in the file
only when the copies just before it in that chain are its recorded predecessors, all of them, in order
(`SceneChains.history`); else (episodes left out, reordered, or copied by a simreel that did not note the scene)
it is not.

`simreel.replay.workers.ReplayWorker` replays the history before an episode in mode ``actions`` (actions only,
nothing compared). The other modes restore recorded states and have tolerances of their own; they replay none.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from simreel.episode import EpisodeMeta

__all__ = ["SceneChains"]


class SceneChains:
    """The chains of one file's episodes, found once (a file may hold tens of thousands of episodes in one chain):
    each episode's chain (`key`), its place among the file's episodes of that chain (`position`), and how many
    episodes ran before it in its scene when it was recorded (`ran_before`)."""

    def __init__(self, episodes: Sequence[EpisodeMeta]) -> None:
        self.key: dict[int, str] = {}
        """Episode index → its chain: ``#<start>`` for a chain recorded in this file (the index of its first
        episode), ``<recording>#<start>`` for copies of a chain recorded there, ``?<index>`` for a copy whose chain
        is unknown."""
        self.ran_before: dict[int, int | None] = {}
        """Episode index → the episodes that ran in its scene before it when it was recorded (None: unknown)."""
        self.recorded: dict[int, tuple[str | None, int]] = {}
        """Episode index → (its recording, None for this file; the index there of its chain's first episode)."""
        current: dict[int, int] = {}
        for ep in sorted(episodes, key=lambda e: e.index):
            scene = ep.origin.get("scene") if ep.origin else None
            if scene is not None:
                self._note(ep, f"{scene['file']}#{scene['start']}", scene["position"], (scene["file"], scene["start"]))
            elif ep.origin:
                self._note(ep, f"?{ep.index}", None, (None, ep.index))
            else:
                if ep.reconfigured or ep.env_idx not in current:
                    current[ep.env_idx] = ep.index
                self._note(ep, f"#{current[ep.env_idx]}", None, (None, current[ep.env_idx]))
        self.members: dict[str, list[EpisodeMeta]] = {}
        """Chain → its episodes in this file, in index order."""
        for ep in sorted(episodes, key=lambda e: e.index):
            self.members.setdefault(self.key[ep.index], []).append(ep)
        self.position = {ep.index: k for chain in self.members.values() for k, ep in enumerate(chain)}
        """Episode index → how many episodes of its chain this file holds before it."""
        for index, ran in self.ran_before.items():
            if ran is None and not self.key[index].startswith("?"):  # recorded here: its place in the chain
                self.ran_before[index] = self.position[index]

    def _note(self, ep: EpisodeMeta, key: str, ran_before: int | None, recorded: tuple[str | None, int]) -> None:
        self.key[ep.index], self.ran_before[ep.index], self.recorded[ep.index] = key, ran_before, recorded

    def history(self, index: int) -> list[EpisodeMeta] | None:
        """The episodes of this file that ran in episode `index`'s scene before it since that scene was built, first
        to last (empty for a chain's first episode); None when this file does not hold them all, in order."""
        ran, k = self.ran_before[index], self.position[index]
        if ran is None or ran > k:
            return None
        before = self.members[self.key[index]][k - ran : k]
        return before if [self.ran_before[ep.index] for ep in before] == list(range(ran)) else None

    def copied_scene(self, index: int, path: str) -> dict[str, Any] | None:
        """``EpisodeMeta.origin["scene"]`` of a copy of episode `index` of this file, at `path` (absolute): its
        recording, the index there of its chain's first episode, and the episodes of that chain that ran before it.
        None where that is unknown (a copy by a simreel that did not note it)."""
        ran, (recording, start) = self.ran_before[index], self.recorded[index]
        if ran is None:
            return None
        return {"file": recording or path, "start": start, "position": ran}
