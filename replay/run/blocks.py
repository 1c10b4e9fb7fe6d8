"""The arrays of a block replay: the recorded states it restores (`RecordedStates`), the preallocated buffers its
replayed rows go into (`BlockBuffers`), and the recorded actions checked before they are stepped (`without_nan`)."""

from __future__ import annotations

import numpy as np

from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeRows
from simreel.model.blocks import StepBlock
from simreel.model.fields import FLAG_FIELDS

__all__ = ["BlockBuffers", "RecordedStates", "without_nan"]


def without_nan(source: EpisodeRows, first: int, actions: np.ndarray) -> np.ndarray:
    """`actions`, the recorded actions of `source` from step `first`; `RecordingFileError` naming the episode and the
    first step whose action holds NaN: ManiSkill's CPU sim refuses to step one (a GPU-sim recording may hold NaN it
    stepped, which no replay here can repeat)."""
    nan = np.isnan(actions).reshape(len(actions), -1).any(axis=1)
    if nan.any():
        where = getattr(source, "path", None) or "the recording"
        raise RecordingFileError(where, f"episode {source.meta.index}: the recorded action of step "
                                        f"{first + int(np.argmax(nan))} holds NaN, which ManiSkill's CPU sim refuses "
                                        "to step (on it, no recorder stepped it: the file was altered or damaged)")
    return actions


class RecordedStates:
    """The recorded states a block replay restores: state row t of the episode, whether it is the last row of the
    block before (or the reset row) or a row of the current block."""

    def __init__(self, reset: StepBlock) -> None:
        self.names = [name for name in reset.arrays if name.startswith("env_states/")]
        self.first = 0
        self._before = {name[len("env_states/"):]: reset[name] for name in self.names}
        self._block: dict[str, np.ndarray] = {}

    def advance(self, first: int, block: StepBlock) -> None:
        """Move to the block of steps `first`.. (its per-state rows: the states after them)."""
        if self._block:
            self._before = {p: a[-1:] for p, a in self._block.items()}
        self.first = first
        self._block = {name[len("env_states/"):]: block[name] for name in self.names}

    def row(self, t: int) -> dict[str, np.ndarray]:
        """State row t (0: after the reset; t: after step t - 1), each leaf (1, ...)."""
        i = t - self.first
        if i == 0:
            return self._before
        return {p: a[i - 1 : i] for p, a in self._block.items()}


class BlockBuffers:
    """Preallocated arrays of the replay of one recorded block (or of the reset row), laid out like it: per-step
    rows, and per-state rows holding the states after those steps (for the reset row: the state after the reset)."""

    def __init__(self, recorded: StepBlock, actions: np.ndarray | None, *, n_channels: int, n_poses: int = 0) -> None:
        k = recorded.rows
        self.per_step = "actions" in recorded.arrays
        self.actions = recorded.get("actions") if actions is None else actions
        self.rewards = np.zeros(k, np.float32)
        for name in FLAG_FIELDS:
            setattr(self, name, np.zeros(k, bool))
        self.env_states = {n[len("env_states/"):]: np.zeros_like(a) for n, a in recorded.arrays.items()
                           if n.startswith("env_states/")}
        self.info = {n[len("info/"):]: np.zeros_like(a) for n, a in recorded.arrays.items() if n.startswith("info/")}
        self.info_returned: set[str] = set()
        """The keys of `info` the task returned at some step of the block (the others hold only their zeros)."""
        self.contact_forces = np.zeros((k, n_channels, 3), np.float32) if n_channels and self.per_step else None
        self.obs: dict[str, np.ndarray] = {}
        self.body_poses = np.zeros((k, n_poses, 7), np.float32) if n_poses else None
        self.rows = k

    def set_state(self, row: int, flat: dict[str, np.ndarray]) -> None:
        for p, dst in self.env_states.items():
            src = flat.get(p)
            if src is not None:
                dst[row] = src[0]

    def set_obs(self, row: int, flat: dict[str, np.ndarray]) -> None:
        for p, a in flat.items():
            dst = self.obs.get(p)
            if dst is None:
                dst = self.obs[p] = np.zeros((self.rows, *a.shape), a.dtype)
            dst[row] = a

    def block(self) -> StepBlock:
        """The replayed rows as flat fields (the reset row: per-state fields only)."""
        arrays: dict[str, np.ndarray] = {}
        if self.per_step:
            arrays.update({"actions": self.actions, "rewards": self.rewards,
                           **{name: getattr(self, name) for name in FLAG_FIELDS}})
            arrays.update({f"info/{k}": a for k, a in self.info.items()})
            if self.contact_forces is not None:
                arrays["contact_forces"] = self.contact_forces
        arrays.update({f"env_states/{p}": a for p, a in self.env_states.items()})
        arrays.update({f"obs/{p}": a for p, a in self.obs.items()})
        if self.body_poses is not None:
            arrays["body_poses"] = self.body_poses
        return StepBlock(arrays, self.rows)
