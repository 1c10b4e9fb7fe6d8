"""World poses of the drawn bodies at each step: from the recording when it holds them, else by restoring
each recorded state into the rebuilt env and reading the bodies' poses. Rows are ``[x y z qw qx qy qz]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from simreel.sim.poses import body_poses_from_states
from simreel.viewers.scene_geometry import SceneBody

__all__ = ["PoseSource", "wxyz_to_xyzw"]


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """SAPIEN's ``[qw qx qy qz]`` → Rerun's ``[qx qy qz qw]`` along the last axis."""
    return np.concatenate([q[..., 1:4], q[..., :1]], axis=-1)


class PoseSource:
    """Poses of `bodies` for any rows of an episode's states.

    When `recorded` (the episode's ``body_poses``, named by `recorded_names`) covers every body, rows are
    sliced from it; otherwise each row's state is restored into `unwrapped` (env 0) and every body is read.
    """

    def __init__(
        self,
        unwrapped: Any,
        bodies: list[SceneBody],
        states: Mapping[str, np.ndarray],
        *,
        recorded: np.ndarray | None = None,
        recorded_names: list[str] | None = None,
    ) -> None:
        self._u = unwrapped
        self._bodies = bodies
        self._states = states
        self._columns: np.ndarray | None = None
        if recorded is not None and recorded_names:
            index = {name: j for j, name in enumerate(recorded_names)}
            if all(b.name in index for b in bodies):
                self._columns = np.array([index[b.name] for b in bodies], np.intp)
                self._recorded = recorded

    @property
    def from_recording(self) -> bool:
        return self._columns is not None

    def rows(self, start: int, stop: int) -> np.ndarray:
        """(stop - start, B, 7) float32 poses of rows [start, stop)."""
        if self._columns is not None:
            return np.asarray(self._recorded[start:stop][:, self._columns], np.float32)
        # every drawn body by its entity: the registry does not name them all (links only one part has)
        return body_poses_from_states(self._u, [b.name for b in self._bodies], self._states, range(start, stop),
                                      entities=[b.entity for b in self._bodies])
