"""What a recorder notes of each sub-scene of its env (`SceneBook`), for each episode that begins there: the seed of
the reset that last built it (`EpisodeMeta.scene_seed`), where it differs from the recording's scene fingerprint
(`EpisodeMeta.scene_changes`), and the chain of episodes it ran since it was built (`EpisodeMeta.chain`)."""

from __future__ import annotations

from typing import Any, NamedTuple

from simreel.model.lineage import SceneChain
from simreel.model.meta import RecordingMeta
from simreel.sim.fingerprint import fingerprint_changes, scene_fingerprint

__all__ = ["SceneBook", "SceneAtReset"]


class SceneAtReset(NamedTuple):
    """What an episode's metadata says of the sub-scene it begins in."""

    scene_seed: int | None
    scene_changes: dict[str, Any]
    chain: SceneChain


class SceneBook:
    """The sub-scenes of ManiSkill env `u`, recorded with metadata `meta`. The env is taken as fresh from
    ``gym.make``, as `simreel.verdicts.scene_history` says: each sub-scene's first episode starts a chain."""

    def __init__(self, u: Any, meta: RecordingMeta) -> None:
        self._u, self._meta, n = u, meta, int(u.num_envs)
        self._seed: list[int | None] = [None] * n
        self._changes: list[dict[str, Any]] = [{} for _ in range(n)]
        self._start = [0] * n
        self._ran = [0] * n
        """Per sub-scene: the index of its chain's first episode, and the episodes committed in that chain."""
        self.rebuilt(range(1, n))  # sub-scene 0's is the recording's own

    def rebuilt(self, envs: Any) -> None:
        """Note where sub-scenes `envs` differ from the recording's scene fingerprint, once the scene was built or
        rebuilt (~3 ms each, never per step)."""
        for i in envs:
            now = scene_fingerprint(self._u, env_idx=i)
            self._changes[i] = fingerprint_changes(self._meta.scene_fingerprint, now)

    def begin(self, i: int, index: int, reconfigured: bool, seed: int | None) -> SceneAtReset:
        """Sub-scene i as episode `index` begins there after a reset with episode seed `seed` that `reconfigured` the
        scene or not: a chain starts at the first committed episode since the scene was built (an episode of no step,
        discarded, ran nothing)."""
        if reconfigured:
            self._seed[i], self._ran[i] = seed, 0
        if not self._ran[i]:
            self._start[i] = index
        return SceneAtReset(self._seed[i], self._changes[i], SceneChain(self._start[i], self._ran[i]))

    def committed(self, i: int) -> None:
        """Sub-scene i's running episode was committed: the next one there is one place further in its chain."""
        self._ran[i] += 1
