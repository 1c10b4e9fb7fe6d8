"""`ReplayedWriter`: writes replayed episodes (``simreel replay -o``) as a simreel recording, in the order they
were asked for, whatever order the workers finish them in."""

from __future__ import annotations

import dataclasses
import datetime
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from simreel.episode import OPTIONAL_STEP_FIELDS, Episode, RecordingMeta
from simreel.formats import format_of
from simreel.state_tree import layout_of

__all__ = ["ReplayOutput", "ReplayedWriter", "output_pose_bodies"]

_PRODUCED = ("versions", *OPTIONAL_STEP_FIELDS)
"""What a replay knows even where the recording did not hold it: this machine's versions, rewards and flags."""


@dataclasses.dataclass(frozen=True)
class ReplayOutput:
    """Where and what `-o` writes: the file, whether it may replace one, the replay's observation mode, the
    bodies whose poses it holds, and the command line kept as provenance."""

    path: str
    overwrite: bool = False
    obs_mode: str | None = None
    pose_bodies: tuple[str, ...] = ()
    command: str = ""
    changes: dict[str, Any] = dataclasses.field(default_factory=dict)
    """`RecordingMeta` fields to set in the output (a conversion: control mode, action space, provenance)."""


def output_pose_bodies(meta: RecordingMeta, output: str | Path | None) -> tuple[str, ...]:
    """Bodies whose poses `-o` writes: those the recording has, or every body when writing MCAP (its transforms)."""
    if output is None:
        return ()
    if meta.pose_bodies:
        return tuple(meta.pose_bodies)
    if format_of(output) != "mcap":
        return ()
    scene = meta.scene or {}
    names = list(scene.get("actors", {}))
    for art, desc in scene.get("articulations", {}).items():
        names += [f"{art}/{link}" for link in desc.get("links", [])]
    return tuple(names)


class ReplayedWriter:
    """Writes replayed episodes to `spec.path` in `order`; the output's metadata is the recording's `meta` with
    the replay's observation layout, contact channels and poses, this machine's versions and the command."""

    def __init__(self, spec: ReplayOutput, meta: RecordingMeta, order: list[int]) -> None:
        self.spec = spec
        self.meta = meta
        self.order = deque(order)
        self.waiting: dict[int, Episode] = {}
        self.writer: Any = None

    def put(self, index: int, episode: Episode | None) -> None:
        """Write episode `index` once those before it in the order are written; None: it has no replay (it could not
        be replayed), go on without it."""
        self.waiting[index] = episode
        while self.order and self.order[0] in self.waiting:
            episode = self.waiting.pop(self.order.popleft())
            if episode is not None:
                self._write(episode)

    def _output_meta(self, episode: Episode) -> RecordingMeta:
        from simreel.sim.make import env_versions

        fields = {
            "obs_mode": self.spec.obs_mode or self.meta.obs_mode,
            "obs_layout": layout_of(episode.obs, batched=True) if episode.obs else {},
            "contact_channels": list(self.meta.contact_channels) if episode.contact_forces is not None else [],
            "pose_bodies": list(self.spec.pose_bodies) if episode.body_poses is not None else [],
            "versions": {k: v for k, v in env_versions().items() if v is not None},
            "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "command": self.spec.command,
            "unknown": [u for u in self.meta.unknown if u not in _PRODUCED],
        }
        return dataclasses.replace(self.meta, **{**fields, **self.spec.changes})

    def _write(self, episode: Episode) -> None:
        from simreel.formats import open_writer

        if self.writer is None:
            self.writer = open_writer(self.spec.path, self._output_meta(episode), overwrite=self.spec.overwrite)
        ep_meta = dataclasses.replace(episode.meta, length=episode.length)
        if episode.length:
            ep_meta.success = bool(episode.success[-1])
            ep_meta.ever_success = bool(np.any(episode.success))
        self.writer.write_episode(dataclasses.replace(episode, meta=ep_meta))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
