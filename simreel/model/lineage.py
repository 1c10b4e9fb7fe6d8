"""Where an episode ran and where it was copied from, as typed records of `EpisodeMeta`:

- `SceneChain` (`EpisodeMeta.chain`): the episode's place in the chain of episodes its recorder's scene ran since it
  was built;
- `ScenePlace`: the same place for an episode made from another recording (a copy's ``origin.scene``, a
  conversion's or a replay's ``provenance["scene"]``), naming that recording;
- `EpisodeOrigin` (`EpisodeMeta.origin`): where a merged or filtered episode was copied from.

Each reads its JSON strictly (`MetadataError` naming the field and what was found) and writes the JSON simreel's
files have always held: ``{}`` where a record is absent. What the records mean for a replay is
`simreel.verdicts.scene_history`'s business.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from simreel.errors import MetadataError

__all__ = ["SceneChain", "ScenePlace", "EpisodeOrigin"]


def _counts(d: Mapping[str, Any], names: tuple[str, ...]) -> bool:
    return all(type(d.get(k)) is int and d[k] >= 0 for k in names)


def _refused(what: str, d: Any, expected: str) -> MetadataError:
    return MetadataError(f"episode metadata: {what} is {json.dumps(d, default=str)[:200]}, expected {expected}")


@dataclass(frozen=True)
class SceneChain:
    """Where its recorder's scene ran an episode: `start`, the index of the first episode that scene ran since it was
    built, and `position`, the episodes it ran before this one (of the recording it was recorded in)."""

    start: int
    position: int

    def to_json(self) -> dict[str, int]:
        return {"start": self.start, "position": self.position}

    @classmethod
    def from_json(cls, d: Any, what: str = "chain") -> SceneChain | None:
        """The chain JSON object `d` holds; None for ``{}`` (unknown: ManiSkill's files, simreel's from before it
        noted it)."""
        if isinstance(d, Mapping) and not d:
            return None
        if not isinstance(d, Mapping) or not _counts(d, ("start", "position")):
            raise _refused(what, d, '{"start": <index>, "position": <count>}')
        return cls(d["start"], d["position"])


@dataclass(frozen=True)
class ScenePlace:
    """Where an episode made from another recording ran when it was recorded: that recording (`file`, its path when
    it was read; `recording`, its `RecordingMeta.recording_id`, empty where it has none) and the episode's place in
    the chain of its scene there (as `SceneChain`)."""

    file: str
    start: int
    position: int
    recording: str = ""

    @property
    def chain_key(self) -> str:
        """The chain this place is in: its recording's id (its path where it has none), and the index there of the
        chain's first episode."""
        return f"{self.recording or self.file}#{self.start}"

    def to_json(self) -> dict[str, Any]:
        named = {"file": self.file, "recording": self.recording} if self.recording else {"file": self.file}
        return {**named, "start": self.start, "position": self.position}

    @classmethod
    def from_json(cls, d: Any, what: str = "scene") -> ScenePlace:
        ok = isinstance(d, Mapping) and isinstance(d.get("file"), str) and _counts(d, ("start", "position")) and \
            isinstance(d.get("recording", ""), str)
        if not ok:
            raise _refused(what, d, '{"file": <path>, "recording": <id>, "start": <index>, "position": <count>}')
        return cls(d["file"], d["start"], d["position"], d.get("recording", ""))

    @classmethod
    def held_by(cls, holder: Mapping[str, Any], what: str) -> ScenePlace | None:
        """The ``"scene"`` entry of JSON object `holder` (an episode's provenance), None where it has none."""
        scene = holder.get("scene")
        return None if scene is None else cls.from_json(scene, f"{what}.scene")


@dataclass(frozen=True)
class EpisodeOrigin:
    """Where a merged or filtered episode was copied from: `file` (absolute path) and `index` there; `scene`, where it
    ran when it was recorded (None where unknown: a copy by a simreel that did not note it); `origin`, that episode's
    own origin when it was a copy too."""

    file: str
    index: int
    scene: ScenePlace | None = None
    origin: EpisodeOrigin | None = None

    @property
    def innermost(self) -> EpisodeOrigin:
        """The origin of the first copy: the recorded episode all copies come from."""
        return self if self.origin is None else self.origin.innermost

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"file": self.file, "index": self.index}
        if self.scene is not None:
            d["scene"] = self.scene.to_json()
        if self.origin is not None:
            d["origin"] = self.origin.to_json()
        return d

    @classmethod
    def from_json(cls, d: Any, what: str = "origin") -> EpisodeOrigin | None:
        """The origin JSON object `d` holds; None for ``{}`` (an episode that is no copy)."""
        if isinstance(d, Mapping) and not d:
            return None
        if not isinstance(d, Mapping) or not isinstance(d.get("file"), str) or not _counts(d, ("index",)):
            raise _refused(what, d, '{"file": <path>, "index": <index there>, "scene": {...}, "origin": {...}}')
        return cls(d["file"], d["index"], ScenePlace.held_by(d, what),
                   cls.from_json(d.get("origin") or {}, f"{what}.origin"))
