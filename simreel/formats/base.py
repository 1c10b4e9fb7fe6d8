"""The reader/writer interface every recording format implements.

Writing streams: `EpisodeWriter.begin_episode` opens an `EpisodeSink` per running episode (one per
parallel env), the recorder appends `StepBlock`s of a few hundred steps, and `commit` makes the
episode durable — after `commit` returns, a `kill -9` of the process must not lose it. Reading is
per episode, so a large file never has to fit in memory.
"""

from __future__ import annotations

import shutil
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import ClassVar

import numpy as np

from simreel.episode import Episode, EpisodeMeta, RecordingMeta
from simreel.errors import RecordingFileError, UsageError

__all__ = ["StepBlock", "EpisodeSink", "EpisodeWriter", "EpisodeReader", "reset_row"]


def reset_row(
    initial_state: dict[str, np.ndarray],
    initial_obs: dict[str, np.ndarray] | None = None,
    initial_poses: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Row 0 (the episode after reset) of the T+1-row fields, as `begin_episode` receives it.

    Keys `env_states/<key path>`, `obs/<key path>` and `body_poses` (stored as float32, like every
    pose row); every array gets a leading axis of 1 row.
    """
    row = {f"env_states/{p}": np.asarray(a)[None] for p, a in initial_state.items()}
    row.update({f"obs/{p}": np.asarray(a)[None] for p, a in (initial_obs or {}).items()})
    if initial_poses is not None:
        row["body_poses"] = np.asarray(initial_poses, dtype=np.float32)[None]
    return row


@dataclass
class StepBlock:
    """k consecutive steps of one episode; every array has k rows (see `simreel.episode`)."""

    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    success: np.ndarray
    fail: np.ndarray
    env_states: dict[str, np.ndarray]
    """The states *after* each of the k steps."""
    obs: dict[str, np.ndarray] = field(default_factory=dict)
    info: dict[str, np.ndarray] = field(default_factory=dict)
    contact_forces: np.ndarray | None = None
    body_poses: np.ndarray | None = None
    """Poses after each of the k steps, when recorded."""

    def __len__(self) -> int:
        return int(self.actions.shape[0])

    @classmethod
    def from_episode(cls, ep: Episode) -> StepBlock:
        """All steps of an episode as one block (its initial state/obs go to `begin_episode`)."""
        return cls(
            actions=ep.actions,
            rewards=ep.rewards,
            terminated=ep.terminated,
            truncated=ep.truncated,
            success=ep.success,
            fail=ep.fail,
            env_states={p: a[1:] for p, a in ep.env_states.items()},
            obs={p: a[1:] for p, a in ep.obs.items()},
            info=dict(ep.info),
            contact_forces=ep.contact_forces,
            body_poses=None if ep.body_poses is None else ep.body_poses[1:],
        )


class EpisodeSink(ABC):
    """One episode being written. Use `append` any number of times, then `commit` or `discard`."""

    @abstractmethod
    def append(self, block: StepBlock) -> None:
        """Write the block; must not keep references to its arrays (they are reused buffers)."""

    @abstractmethod
    def commit(self, meta: EpisodeMeta) -> None:
        """Make the episode durable in the file, with its final metadata (length, success, ...)."""

    @abstractmethod
    def discard(self) -> None:
        """Drop the episode (e.g. a reset before any step); nothing of it stays on disk."""


class EpisodeWriter(ABC):
    """Writes one recording file. A context manager; `close` commits nothing that was not committed."""

    records_poses_by_default: ClassVar[bool] = False
    """Whether a recorder writing this format records body poses unless told otherwise."""

    def __init__(self, path: str | Path, meta: RecordingMeta) -> None:
        self.path = Path(path)
        self.meta = meta

    @classmethod
    def side_paths(cls, path: Path) -> list[Path]:
        """Files and folders this format writes beside the recording `path` (none unless a format has some)."""
        return []

    @classmethod
    def check_target(cls, path: Path, *, overwrite: bool) -> None:
        """Raise `UsageError` if a new recording cannot go to `path`: its folder is missing, or (without
        `overwrite`) it or one of its side paths already exists. Cheap: touches nothing."""
        if not path.parent.is_dir():
            raise UsageError(f"cannot write {path}: folder {path.parent} does not exist")
        if overwrite:
            return
        if path.exists():
            raise UsageError(f"{path} already exists; pass --overwrite to replace it")
        for side in cls.side_paths(path):
            if side.exists():
                raise UsageError(
                    f"{side} already exists and a recording to {path.name} would replace it; "
                    "pass --overwrite to replace it"
                )

    @classmethod
    def remove(cls, path: Path) -> None:
        """Delete the recording `path` and its side paths; those that do not exist are skipped."""
        path.unlink(missing_ok=True)
        for side in cls.side_paths(path):
            if side.is_dir() and not side.is_symlink():
                shutil.rmtree(side, ignore_errors=True)
            else:
                side.unlink(missing_ok=True)

    @abstractmethod
    def begin_episode(
        self,
        meta: EpisodeMeta,
        initial_state: dict[str, np.ndarray],
        initial_obs: dict[str, np.ndarray] | None = None,
        initial_poses: np.ndarray | None = None,
    ) -> EpisodeSink:
        """Start an episode whose state after reset is `initial_state` (flat, one env, no batch dim).

        `initial_poses` (B, 7) is given when `meta.pose_bodies` is not empty.
        """

    def write_episode(self, episode: Episode) -> None:
        """Write a whole in-memory episode (convert, `replay -o`)."""
        episode.check_shapes()
        sink = self.begin_episode(
            episode.meta,
            {p: a[0] for p, a in episode.env_states.items()},
            {p: a[0] for p, a in episode.obs.items()} or None,
            None if episode.body_poses is None else episode.body_poses[0],
        )
        if episode.length:
            sink.append(StepBlock.from_episode(episode))
        sink.commit(episode.meta)

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> EpisodeWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class EpisodeReader(ABC):
    """Reads one recording file: `meta`, the list of `episodes` (metadata only) and each episode's data."""

    path: Path
    meta: RecordingMeta
    episodes: list[EpisodeMeta]

    @abstractmethod
    def read_episode(self, index: int) -> Episode:
        """The episode whose `EpisodeMeta.index` is `index`."""

    def __len__(self) -> int:
        return len(self.episodes)

    def __iter__(self) -> Iterator[Episode]:
        for m in self.episodes:
            yield self.read_episode(m.index)

    def episode_meta(self, index: int) -> EpisodeMeta:
        for m in self.episodes:
            if m.index == index:
                return m
        have = ", ".join(str(m.index) for m in self.episodes) or "none"
        raise RecordingFileError(self.path, f"no episode {index} (episodes: {have})")

    def close(self) -> None:  # noqa: B027 - optional hook
        pass

    def __enter__(self) -> EpisodeReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
