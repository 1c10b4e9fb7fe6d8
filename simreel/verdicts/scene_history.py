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
simreel's recorder notes each episode's chain and place (`EpisodeMeta.chain`), so that one its file lacks (damaged,
or lost by ``recover``) leaves a gap that is noticed; in files without it, the order of the episodes held tells.

An episode copied by ``simreel filter`` or ``merge`` keeps where it ran (``EpisodeMeta.origin.scene``,
`SceneChains.copied_scene`): its recording (by its `RecordingMeta.recording_id`: a moved file is the same recording,
a new one recorded at the same path is not; by its path where it has none), the index there of its chain's first
episode and its place in that chain; so does a converted one (``provenance["scene"]``: the input's chain for a
re-render, the conversion's own run for a control-mode conversion, `run_scenes`). A file's episodes made from one
recorded chain form a chain of that file, whose history at each place is any of its episodes at that place (copies
of one recorded episode); an episode's history is in the file when the file holds an episode at every place before
it (`SceneChains.complete`), else (episodes left out, or made from another recording by a simreel that did not note
the scene: a copy, a conversion, a replay's output) it is not.

`simreel.replay.run.workers.ReplayWorker` replays the history before an episode in mode ``actions`` (actions only,
nothing compared). The other modes restore recorded states and have tolerances of their own; they replay none, but
re-run the last step of the episode before (`SceneChains.previous`): the observations at a reset read its contacts
(`simreel.replay.run.history.step_before`).
"""

from __future__ import annotations

from collections.abc import Sequence

from simreel.model.lineage import ScenePlace
from simreel.model.meta import EpisodeMeta

__all__ = ["SceneChains", "recorded_scene", "run_scenes"]


def recorded_scene(episode: EpisodeMeta) -> ScenePlace | None:
    """Where `episode` says it ran, if it was made from another recording: ``provenance["scene"]`` of a converted
    episode (first: a control-mode conversion of a copy ran in its own run), else ``origin.scene`` of a copy
    (filter, merge); None for an episode recorded in its file (or a copy that does not say)."""
    converted = episode.provenance.scene if episode.provenance is not None else None
    return converted or (episode.origin.scene if episode.origin is not None else None)


def run_scenes(episodes: Sequence[EpisodeMeta], path: str, recording_id: str) -> dict[int, ScenePlace]:
    """Where each of `episodes` ran when a run (a control-mode conversion writing the recording at `path`, whose
    `RecordingMeta.recording_id` is `recording_id`) stepped them one after another, in this order, in one env: its
    scene, as `recorded_scene` reads it. A reset that rebuilt the scene starts a chain."""
    scenes: dict[int, ScenePlace] = {}
    start, ran = None, 0
    for ep in episodes:
        if start is None or ep.reconfigured:
            start, ran = ep.index, 0
        scenes[ep.index] = ScenePlace(path, start, ran, recording_id)
        ran += 1
    return scenes


class SceneChains:
    """The chains of one file's episodes, found once (a file may hold tens of thousands of episodes in one chain):
    each episode's chain (`key`) and how many episodes ran before it in its scene when it was recorded
    (`ran_before`, its place in the chain). Any two episodes of one chain at one place are the same recorded episode
    (two copies of it), so a chain's history is its episodes at places 0, 1, ..., whichever copies hold them."""

    def __init__(self, episodes: Sequence[EpisodeMeta]) -> None:
        self.key: dict[int, str] = {}
        """Episode index → its chain: ``#<start>`` for a chain recorded in this file (the index of its first
        episode), ``<recording>#<start>`` for episodes made from a chain recorded there (its `recording_id`, else
        its path), ``?<index>`` for a copy whose chain is unknown."""
        self.ran_before: dict[int, int | None] = {}
        """Episode index → the episodes that ran in its scene before it when it was recorded (None: unknown)."""
        self._recorded: dict[int, tuple[tuple[str, str] | None, int]] = {}
        """Episode index → (its recording: (path, `RecordingMeta.recording_id`), None for this file; the index there
        of its chain's first episode)."""
        self._at: dict[str, dict[int, list[EpisodeMeta]]] = {}
        """Chain → place → its episodes in this file at that place, in index order."""
        current: dict[int, tuple[int, int]] = {}  # sub-scene → (its chain's first episode, episodes in it so far)
        inferred = _inferred_scenes([ep for ep in episodes if ep.origin is not None])
        placed = _places_by_index([ep for ep in episodes if not (ep.origin or ep.chain) and _made_elsewhere(ep)])
        for ep in sorted(episodes, key=lambda e: e.index):
            scene = recorded_scene(ep) or inferred.get(ep.index)
            if scene is not None:
                self._note(ep, scene.chain_key, scene.position, ((scene.file, scene.recording), scene.start))
            elif ep.origin is not None:
                self._note(ep, f"?{ep.index}", None, (None, ep.index))
            elif ep.chain or not _made_elsewhere(ep):
                start, ran = _own_place(ep, current)
                self._note(ep, f"#{start}", ran, (None, start))
            elif ep.index in placed:
                start, ran = placed[ep.index]
                self._note(ep, f"#{start}", ran, (None, start))
            else:
                self._note(ep, f"?{ep.index}", None, (None, ep.index))
        self._complete = {key: next(p for p in range(len(at) + 1) if p not in at) for key, at in self._at.items()}
        """Chain → its first place this file holds no episode at: the chain is whole here up to it."""

    def _note(self, ep: EpisodeMeta, key: str, ran_before: int | None,
              recorded: tuple[tuple[str, str] | None, int]) -> None:
        self.key[ep.index], self.ran_before[ep.index], self._recorded[ep.index] = key, ran_before, recorded
        if ran_before is not None:
            self._at.setdefault(key, {}).setdefault(ran_before, []).append(ep)

    def complete(self, index: int) -> bool:
        """Whether this file holds every episode that ran in episode `index`'s scene before it since that scene was
        built (true for a chain's first episode)."""
        ran = self.ran_before[index]
        return ran is not None and ran <= self._complete[self.key[index]]

    def history(self, index: int, since: int = 0) -> list[EpisodeMeta]:
        """The episodes that ran in episode `index`'s scene before it since that scene was built, from place `since`
        on, first to last: at each place, the copy last before `index` in this file, else the first. The file must
        hold them (`complete`)."""
        at = self._at[self.key[index]]
        return [_nearest_before(at[p], index) for p in range(since, self.ran_before[index] or 0)]

    def previous(self, index: int) -> EpisodeMeta | None:
        """The episode that ran in episode `index`'s scene right before it (the copy `history` would pick); None
        when this file does not hold it, or `index` is a chain's first episode (``ran_before`` 0) or of an unknown
        place (None)."""
        ran = self.ran_before[index]
        copies = self._at[self.key[index]].get(ran - 1) if ran else None
        return _nearest_before(copies, index) if copies else None

    def copied_scene(self, index: int, path: str, recording_id: str) -> ScenePlace | None:
        """``EpisodeMeta.origin.scene`` of a copy of episode `index` of this file, at `path` (absolute), whose
        `RecordingMeta.recording_id` is `recording_id`: its recording, the index there of its chain's first episode,
        and the episodes of that chain that ran before it. None where that is unknown (a copy by a simreel that did
        not note it)."""
        ran, (recording, start) = self.ran_before[index], self._recorded[index]
        if ran is None:
            return None
        file, recording_id = recording or (path, recording_id)
        return ScenePlace(file, start, ran, recording_id)


def _made_elsewhere(ep: EpisodeMeta) -> bool:
    """Whether `ep` was made from an episode of another recording: a copy (``origin``), a conversion (its
    ``provenance``) or a replay's output (its ``verification``). Where such an episode says neither where it ran nor
    its place (a simreel older than those notes wrote it), the order of its file does not tell its place: ``convert
    --episodes 0,2`` wrote episode 2 right after 0."""
    return ep.origin is not None or ep.provenance is not None or ep.verification is not None


def _places_by_index(made: Sequence[EpisodeMeta]) -> dict[int, tuple[int, int]]:
    """(its chain's first episode, its place there) of each episode of `made` that a conversion or a replay's output
    wrote without noting where it ran (`_made_elsewhere`), where its index (that of the episode it was made from:
    both keep it) tells: as for older copies (`_walk`), from one whose reset rebuilt the scene or that was its
    recording's first, each made from the episode right after the one before it. Only for recordings of one env; the
    others are unknown (left out)."""
    if not all(ep.env_idx == 0 for ep in made):
        return {}
    walked = _walk("", sorted(((ep.index, ep) for ep in made), key=lambda x: x[0]))
    return {index: (scene.start, scene.position) for index, scene in walked.items()}


def _own_place(ep: EpisodeMeta, current: dict[int, tuple[int, int]]) -> tuple[int, int]:
    """(its chain's first episode, its place there) of `ep`, recorded in the file being read: as its recorder noted
    (`EpisodeMeta.chain`), else by the file's order, `current` holding each sub-scene's chain so far."""
    if ep.chain is not None:
        return ep.chain.start, ep.chain.position
    start, ran = (ep.index, 0) if ep.reconfigured or ep.env_idx not in current else current[ep.env_idx]
    current[ep.env_idx] = (start, ran + 1)
    return start, ran


def _nearest_before(copies: list[EpisodeMeta], index: int) -> EpisodeMeta:
    before = [ep for ep in copies if ep.index < index]
    return before[-1] if before else copies[0]


def _inferred_scenes(copies: Sequence[EpisodeMeta]) -> dict[int, ScenePlace]:
    """Where copies made by a simreel that did not note it (no scene, `recorded_scene`) ran, where their metadata
    tells: the recording's episodes they were copied from (the innermost ``origin``), in their order there, from one
    whose reset rebuilt the scene, that was the recording's first, or whose copy says where it ran, each copied from
    the episode right after the one before it. Only for recordings of one env (``env_idx`` 0): those of parallel
    envs interleave their sub-scenes' episodes. The others are unknown (left out)."""
    by_recording: dict[str, list[tuple[int, EpisodeMeta]]] = {}
    for ep in copies:
        root = ep.origin.innermost
        by_recording.setdefault(root.file, []).append((root.index, ep))
    scenes: dict[int, ScenePlace] = {}
    for recording, listed in by_recording.items():
        if all(ep.env_idx == 0 for _, ep in listed):
            scenes.update(_walk(recording, sorted(listed, key=lambda x: x[0])))
    return scenes


def _walk(recording: str, listed: list[tuple[int, EpisodeMeta]]) -> dict[int, ScenePlace]:
    """`_inferred_scenes` of the copies of one recording, (index there, copy) in that index order."""
    scenes: dict[int, ScenePlace] = {}
    chain: tuple[int, int] | None = None  # (its first episode there, the place of the last one)
    last = None
    for at, ep in listed:
        noted = recorded_scene(ep)
        if noted is not None:
            chain = (noted.start, noted.position)
        elif ep.reconfigured or at == 0:
            chain = (at, 0)
        elif chain is not None and last is not None and at == last + 1:
            chain = (chain[0], chain[1] + 1)
        elif at != last:  # (the same episode copied twice keeps its place)
            chain = None
        last = at
        if chain is not None and noted is None:
            scenes[ep.index] = ScenePlace(recording, chain[0], chain[1])
    return scenes
