"""What simreel's MCAP writer and reader share: topics, the time base, and the metadata records.

Metadata records, each a dataclass with its `to_metadata` (write) and `from_metadata` (read) side by side:

- `RecordingRecord` (name ``simreel``): format version, `RecordingMeta` JSON, channel ids, field tables.
- `EpisodeBeginRecord` (``simreel.episode_begin.<i>``): an episode began (its env lane, start time, seed).
- `EpisodeRecord` (``simreel.episode.<i>``): an episode was committed (`EpisodeMeta`, time span, steps).
- `EpisodeDiscardRecord` (``simreel.episode_discard.<i>``): an episode was dropped.

One name per record: Rerun merges records of the same name. See `simreel.formats.mcap` for the layout.
Each record carries its own checksum (`seal`, checked by `unseal`), so a damaged record is found without reading
the whole data section whose checksum MCAP keeps.
"""

from __future__ import annotations

import datetime
import json
import time
import zlib
from dataclasses import dataclass
from typing import Any

from simreel.model.json_input import json_value
from simreel.model.meta import EpisodeMeta, RecordingMeta

__all__ = [
    "MCAP_MAGIC",
    "COMPRESSIONS",
    "TOPICS",
    "WORLD_FRAME",
    "step_ns_of",
    "time_origin_of",
    "RecordingRecord",
    "EpisodeBeginRecord",
    "EpisodeRecord",
    "EpisodeDiscardRecord",
    "record_kind",
    "record_name",
    "seal",
    "unseal",
]

SEAL_KEY = "crc32"

MCAP_MAGIC = b"\x89MCAP0\r\n"
COMPRESSIONS = ("zstd", "lz4", "none")
TOPICS = {"reset": "/simreel/reset", "steps": "/simreel/steps", "tf": "/tf", "scene": "/scene",
          "robot_description": "/robot_description", "plots": "/plots", "log": "/log"}
WORLD_FRAME = "world"


def _utf8(text: str) -> str:
    """`text` as UTF-8 can encode it (MCAP's metadata strings are UTF-8): a lone surrogate, which Python makes of a
    command line argument that is no UTF-8 (a file name), written as its escape; `recording_meta` keeps it exactly."""
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def step_ns_of(meta: RecordingMeta) -> int:
    """Nanoseconds of log time per env step: the control period (1 s when the recording lacks it)."""
    return int(round(1e9 / meta.control_freq)) if meta.control_freq else 1_000_000_000


def time_origin_of(meta: RecordingMeta) -> int:
    """The log time (ns since the Unix epoch) of a recording's first row: when it was made (`created_utc`, else now,
    to the second), so that viewers show the recording's date rather than 1970 (files written before started at 0)."""
    try:
        made = datetime.datetime.fromisoformat(meta.created_utc)
    except ValueError:
        return int(time.time()) * 1_000_000_000
    if made.tzinfo is None:
        made = made.replace(tzinfo=datetime.timezone.utc)
    return int(made.timestamp()) * 1_000_000_000


def record_kind(name: str) -> str:
    """The record name without its episode index: ``simreel.episode.3`` → ``simreel.episode``."""
    return name if name == RecordingRecord.NAME else name.rsplit(".", 1)[0]


@dataclass(frozen=True)
class RecordingRecord:
    """The recording's metadata record: everything a reader needs before any message."""

    NAME = "simreel"
    format_version: int
    simreel_version: str
    meta: RecordingMeta
    step_ns: int
    channels: dict[str, int]
    reset_schema: bytes
    step_schema: bytes
    time_origin_ns: int = 0
    """Log time of the first episode's first row (0 in files written before simreel kept one)."""

    def to_metadata(self) -> dict[str, str]:
        m = self.meta
        return {
            "format_version": str(self.format_version),
            "simreel_version": self.simreel_version,
            "env_id": _utf8(m.env_id),
            "control_mode": _utf8(str(m.control_mode)),
            "command": _utf8(m.command),
            "created_utc": _utf8(m.created_utc),
            "step_ns": str(self.step_ns),
            "time": "log_time = episode start + row x step_ns; row 0 is the state after reset; the first episode "
                    "starts at time_origin_ns (ns since the Unix epoch: when the recording was made)",
            "time_origin_ns": str(self.time_origin_ns),
            "pose_source": "recorded body poses" if m.pose_bodies else "state dict (actors, articulation roots)",
            "channels": json.dumps(self.channels),
            "reset_fields": self.reset_schema.decode(),
            "step_fields": self.step_schema.decode(),
            "recording_meta": json.dumps(m.to_json()),
        }

    @classmethod
    def from_metadata(cls, d: dict[str, str]) -> RecordingRecord:
        """Raises KeyError/ValueError/TypeError on a malformed record (the reader names the file)."""
        return cls(
            format_version=int(d.get("format_version", "0")),
            simreel_version=d.get("simreel_version", ""),
            meta=RecordingMeta.from_json(json_value(d["recording_meta"], "its recording_meta")),
            step_ns=int(d.get("step_ns", "0")),
            channels={k: int(v) for k, v in json_value(d["channels"], "its channels").items()},
            reset_schema=d["reset_fields"].encode(),
            step_schema=d["step_fields"].encode(),
            time_origin_ns=int(d.get("time_origin_ns", "0")),
        )

    @staticmethod
    def version_of(d: dict[str, str]) -> int:
        """The format version a record states, read before anything else is trusted."""
        return int(d.get("format_version", "0"))


@dataclass(frozen=True)
class EpisodeBeginRecord:
    NAME = "simreel.episode_begin"
    index: int
    env_idx: int
    start_ns: int
    seed: int | None

    def to_metadata(self) -> dict[str, str]:
        return {"index": str(self.index), "env_idx": str(self.env_idx), "start_ns": str(self.start_ns),
                "seed": str(self.seed)}

    @classmethod
    def from_metadata(cls, d: dict[str, str]) -> EpisodeBeginRecord:
        seed = d.get("seed", "None")
        return cls(int(d["index"]), int(d.get("env_idx", "0")), int(d.get("start_ns", "0")),
                   None if seed == "None" else int(seed))


@dataclass(frozen=True)
class EpisodeRecord:
    NAME = "simreel.episode"
    meta: EpisodeMeta
    start_ns: int
    end_ns: int
    steps: int

    def to_metadata(self) -> dict[str, str]:
        return {"index": str(self.meta.index), "episode": json.dumps(self.meta.to_json()),
                "start_ns": str(self.start_ns), "end_ns": str(self.end_ns), "steps": str(self.steps)}

    @classmethod
    def from_metadata(cls, d: dict[str, str]) -> EpisodeRecord:
        return cls(EpisodeMeta.from_json(json_value(d["episode"], "its episode")), int(d["start_ns"]), int(d["end_ns"]),
                   int(d["steps"]))


@dataclass(frozen=True)
class EpisodeDiscardRecord:
    NAME = "simreel.episode_discard"
    index: int
    steps: int

    def to_metadata(self) -> dict[str, str]:
        return {"index": str(self.index), "steps": str(self.steps)}

    @classmethod
    def from_metadata(cls, d: dict[str, str]) -> EpisodeDiscardRecord:
        return cls(int(d["index"]), int(d.get("steps", "0")))


def record_name(record: Any) -> str:
    """The metadata record name a record is written under (per-episode records carry their index)."""
    if isinstance(record, RecordingRecord):
        return RecordingRecord.NAME
    index = record.meta.index if isinstance(record, EpisodeRecord) else record.index
    return f"{record.NAME}.{index}"


def _crc(d: dict[str, str]) -> str:
    return f"{zlib.crc32(json.dumps(sorted(d.items()), separators=(',', ':')).encode()):08x}"


def seal(d: dict[str, str]) -> dict[str, str]:
    """A metadata record's map with the CRC-32 of its content added (key `crc32`)."""
    return {**d, SEAL_KEY: _crc(d)}


def unseal(d: dict[str, str]) -> dict[str, str]:
    """The content of a record sealed by `seal`; ValueError when it does not match its CRC (a damaged record).
    Records of earlier versions carry none and are returned as they are."""
    if SEAL_KEY not in d:
        return d
    content = {k: v for k, v in d.items() if k != SEAL_KEY}
    if _crc(content) != d[SEAL_KEY]:
        raise ValueError("the record does not match its checksum (damaged)")
    return content
