"""Where an episode ran and where it was copied from, as typed records of `EpisodeMeta`:

- `SceneChain` (`EpisodeMeta.chain`): the episode's place in the chain of episodes its recorder's scene ran since it
  was built;
- `ScenePlace`: the same place for an episode made from another recording (a copy's ``origin.scene``, a
  conversion's or a replay's ``provenance["scene"]``), naming that recording;
- `EpisodeOrigin` (`EpisodeMeta.origin`): where a merged or filtered episode was copied from;
- `EpisodeProvenance` (`EpisodeMeta.provenance`): how a converted episode was made and judged, and where a
  conversion or a replay ran it;
- `EpisodeVerification` (`EpisodeMeta.verification`): the verdict of the replay that wrote an episode.

Each reads its JSON strictly (`MetadataError` naming the field and what was found) and writes the JSON simreel's
files have always held: ``{}`` where a record is absent. What the records mean for a replay is
`simreel.verdicts.scene_history`'s business.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from simreel.errors import MetadataError

__all__ = ["SceneChain", "ScenePlace", "EpisodeOrigin", "EpisodeProvenance", "EpisodeVerification"]


def _counts(d: Mapping[str, Any], names: tuple[str, ...]) -> bool:
    return all(type(d.get(k)) is int and d[k] >= 0 for k in names)


def _absent(d: Any) -> bool:
    """Whether JSON value `d` is ``{}``: the record is absent."""
    return isinstance(d, Mapping) and not d


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
        if _absent(d):
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
        if _absent(d):
            return None
        if not isinstance(d, Mapping) or not isinstance(d.get("file"), str) or not _counts(d, ("index",)):
            raise _refused(what, d, '{"file": <path>, "index": <index there>, "scene": {...}, "origin": {...}}')
        return cls(d["file"], d["index"], ScenePlace.held_by(d, what),
                   cls.from_json(d.get("origin") or {}, f"{what}.origin"))


def _str_list(d: Mapping[str, Any], key: str) -> bool:
    value = d.get(key, [])
    return isinstance(value, list) and all(isinstance(x, str) for x in value)


def _optional(d: Mapping[str, Any], key: str, types: type | tuple[type, ...]) -> bool:
    value = d.get(key)
    return value is None or (isinstance(value, types) and not isinstance(value, bool))


_CONVERSION_KEYS = ("source_episode", "verdict", "checked", "first_exceeded", "max_error")
"""What a conversion writes of each episode it converted (`EpisodeProvenance`), ``clipped_steps`` and ``scene``
aside."""


@dataclass(frozen=True)
class EpisodeProvenance:
    """How an episode made from another recording was made (`EpisodeMeta.provenance`). For an episode of a converted
    recording: the episode it converts (`source_episode`, its index in the source), the conversion's verdict on it,
    the groups it `checked`, the first error past its tolerance (`first_exceeded`: a
    `simreel.verdicts.compare.Divergence`'s JSON, None where none was), the largest error per key (`max_error`: a
    float, or its text where not finite) and, for a control-mode conversion, the steps whose converted action was
    clipped (`clipped_steps`). For either a conversion or a replay's output (``simreel replay -o``): the `scene` it ran
    in (`ScenePlace`, None where unknown or states were restored). `others`: keys this version does not know, kept as
    they were."""

    source_episode: int | None = None
    verdict: str | None = None
    checked: tuple[str, ...] = ()
    first_exceeded: dict[str, Any] | None = None
    max_error: dict[str, float | str] = field(default_factory=dict)
    clipped_steps: int | None = None
    scene: ScenePlace | None = None
    others: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON simreel has always written: a conversion's keys where it is one (`source_episode` set), then
        ``clipped_steps`` and ``scene`` where known."""
        d: dict[str, Any] = dict(self.others)
        if self.source_episode is not None:
            d.update(source_episode=self.source_episode, verdict=self.verdict, checked=list(self.checked),
                     first_exceeded=self.first_exceeded, max_error=dict(self.max_error))
        if self.clipped_steps is not None:
            d["clipped_steps"] = self.clipped_steps
        if self.scene is not None:
            d["scene"] = self.scene.to_json()
        return d

    @classmethod
    def from_json(cls, d: Any, what: str = "provenance") -> EpisodeProvenance | None:
        """The provenance JSON object `d` holds; None for ``{}`` (an episode recorded in its file)."""
        if _absent(d):
            return None
        if not isinstance(d, Mapping) or not cls._valid(d):
            raise _refused(what, d, '{"source_episode": <index>, "verdict": <verdict>, "checked": [...], '
                                    '"first_exceeded": {...} | null, "max_error": {...}, "scene": {...}}')
        known = {*_CONVERSION_KEYS, "clipped_steps", "scene"}
        return cls(d.get("source_episode"), d.get("verdict"), tuple(d.get("checked", ())), d.get("first_exceeded"),
                   dict(d.get("max_error") or {}), d.get("clipped_steps"), ScenePlace.held_by(d, what),
                   {k: v for k, v in d.items() if k not in known})

    @staticmethod
    def _valid(d: Mapping[str, Any]) -> bool:
        return (("source_episode" not in d or _counts(d, ("source_episode",))) and _optional(d, "verdict", str)
                and _str_list(d, "checked") and _optional(d, "first_exceeded", Mapping)
                and isinstance(d.get("max_error", {}), Mapping)
                and ("clipped_steps" not in d or _counts(d, ("clipped_steps",))))


@dataclass(frozen=True)
class EpisodeVerification:
    """The verdict of the replay that wrote an episode (``simreel replay -o``; `EpisodeMeta.verification`): its
    `verdict`, and as their JSON (`simreel.replay.report.report.EpisodeReport.verification`) the first divergence,
    the scene differences found at the reset (None: not compared) and the explanation of a divergence, for viewers
    of that file."""

    verdict: str
    first_divergence: dict[str, Any] | None = None
    scene_differences: list[dict[str, Any]] | None = None
    explanation: dict[str, Any] | None = None
    others: dict[str, Any] = field(default_factory=dict)
    """Keys this version does not know, kept as they were."""

    def to_json(self) -> dict[str, Any]:
        return {**self.others, "verdict": self.verdict, "first_divergence": self.first_divergence,
                "scene_differences": self.scene_differences, "explanation": self.explanation}

    @classmethod
    def from_json(cls, d: Any, what: str = "verification") -> EpisodeVerification | None:
        """The verification JSON object `d` holds; None for ``{}`` (an episode no replay wrote)."""
        if _absent(d):
            return None
        differences = d.get("scene_differences") if isinstance(d, Mapping) else None
        ok = (isinstance(d, Mapping) and isinstance(d.get("verdict"), str) and _optional(d, "first_divergence", Mapping)
              and (differences is None or (isinstance(differences, list)
                                           and all(isinstance(x, Mapping) for x in differences)))
              and _optional(d, "explanation", Mapping))
        if not ok:
            raise _refused(what, d, '{"verdict": <verdict>, "first_divergence": {...} | null, '
                                    '"scene_differences": [...] | null, "explanation": {...} | null}')
        others = {k: v for k, v in d.items() if k not in ("verdict", "first_divergence", "scene_differences",
                                                          "explanation")}
        return cls(d["verdict"], d.get("first_divergence"), differences, d.get("explanation"), others)
