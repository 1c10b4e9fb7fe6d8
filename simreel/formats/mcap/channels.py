"""`McapChannels`: the channels of one MCAP recording being written, and every message and record on them.

It owns the open `mcap.writer.Writer`: it registers the schemas and channels, writes an episode's reset row,
its blocks of steps (exact data, `/tf` transforms, `/plots` scalars), its `/log` lines and its metadata
records, the scene's geometry (`/scene`, `/robot_description`) as the first episode in a new scene begins, and
closes chunks when an episode is committed. An episode's place in the file is an `EpisodeLane`
(its index, env, start time and rows so far). `McapWriter` and its sinks call nothing else.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import IO, Any

import numpy as np

from simreel import FORMAT_VERSION, __version__
from simreel.formats.mcap.blocks import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    fields_to_schema,
    pack_block,
    reset_fields,
    step_fields,
)
from simreel.formats.mcap.foxglove import (
    FRAME_TRANSFORMS_SCHEMA,
    LOG_INFO,
    LOG_SCHEMA,
    LOG_WARNING,
    FrameTransformsEncoder,
    encode_log,
)
from simreel.formats.mcap.records import (
    TOPICS,
    WORLD_FRAME,
    EpisodeBeginRecord,
    EpisodeDiscardRecord,
    EpisodeRecord,
    RecordingRecord,
    record_name,
    seal,
    step_ns_of,
    time_origin_of,
)
from simreel.formats.mcap.scene import (
    ROBOT_DESCRIPTION_SCHEMA,
    SCENE_UPDATE_SCHEMA,
    encode_ros2_string,
    scene_messages,
)
from simreel.model.fields import FLAG_FIELDS
from simreel.model.geometry import SceneGeometry
from simreel.model.meta import EpisodeMeta, RecordingMeta

__all__ = ["EpisodeLane", "McapChannels"]


@dataclass
class EpisodeLane:
    """An episode's place on the time axis: `log_time = start_ns + row × step_ns`, row 0 after reset."""

    index: int
    env: int
    start_ns: int
    rows: int = 0
    """Steps written so far."""


def _view_frames(meta: RecordingMeta) -> tuple[list[str], list[str] | None]:
    """Body names on `/tf` and, without recorded poses, the state key path each pose is read from (the
    first 7 floats of an actor's or articulation's state are its root pose `[x y z qw qx qy qz]`)."""
    if meta.pose_bodies:
        return list(meta.pose_bodies), None
    names: list[str] = []
    sources: list[str] = []
    arts = meta.scene.get("articulations", {})
    for path, spec in meta.state_layout.items():
        kind, _, name = path.partition("/")
        if len(spec.shape) != 1 or spec.shape[0] < 7 or not name or kind not in ("actors", "articulations"):
            continue
        links = (arts.get(name, {}).get("links") or []) if kind == "articulations" else []
        names.append(f"{name}/{links[0]}" if links else name)
        sources.append(path)
    return names, sources


def _short_float32(a: np.ndarray) -> np.ndarray:
    """float32 values as the float64 of a decimal with 8 significant digits (9 where 8 do not read back as
    the same float32; the widened value itself where neither does): `0.100000001` rather than the
    `0.10000000149011612` of its float64 widening. JSON then holds the same float32 numbers in fewer bytes."""
    x = a.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        magnitude = np.floor(np.log10(np.abs(x)))
    magnitude[~np.isfinite(magnitude)] = 0
    out = x
    for digits in (9, 8):
        scale = 10.0 ** (digits - 1 - magnitude)
        with np.errstate(over="ignore", invalid="ignore"):
            rounded = np.round(x * scale) / scale
        out = np.where(rounded.astype(np.float32) == a, rounded, out)
    return out


def _json_column(a: Any) -> list[Any]:
    """Rows of `a` as JSON values; NaN/inf become null (JSON has no such numbers; the exact values are in
    `/simreel/steps`), float32 values are written short (`_short_float32`)."""
    a = np.asarray(a)
    if a.dtype.kind == "f":
        finite = np.isfinite(a)
        a = _short_float32(a) if a.dtype == np.float32 else a.astype(np.float64)
        if not finite.all():
            a = a.astype(object)
            a[~finite] = None
    return a.tolist()


class McapChannels:
    """Registers simreel's channels on `mcap` (a started `mcap.writer.Writer` over `fh`) and writes to them."""

    def __init__(self, mcap: Any, fh: IO[bytes], meta: RecordingMeta, *, fsync: bool = False) -> None:
        self._mcap = mcap
        self._fh = fh
        self._fsync = fsync
        self.meta = meta
        self.step_ns = step_ns_of(meta)
        self.origin_ns = time_origin_of(meta)
        """Log time of the first episode's first row (`simreel.formats.mcap.records.time_origin_of`)."""
        self._reset_fields = reset_fields(meta)
        self._step_fields = step_fields(meta)
        self._frames, self._pose_sources = _view_frames(meta)
        self._encoders: dict[int, FrameTransformsEncoder] = {}
        self._scenes: dict[int, SceneGeometry] = {}
        """Each sub-scene's geometry given since its last episode began (`scene`), written as its next one begins."""
        self._scene_written: dict[int, tuple[bytes, tuple[str, ...]]] = {}
        """Each sub-scene's last scene written: its SceneUpdate bytes and entity ids."""
        self._ids = self._register()
        self._record(RecordingRecord(FORMAT_VERSION, __version__, meta, self.step_ns, self._ids,
                                     fields_to_schema(self._reset_fields), fields_to_schema(self._step_fields),
                                     time_origin_ns=self.origin_ns))
        fh.flush()

    def time(self, lane: EpisodeLane, row: int) -> int:
        return lane.start_ns + row * self.step_ns

    # ---------------------------------------------------------------- header
    def _register(self) -> dict[str, int]:
        m = self._mcap
        ids: dict[str, int] = {}
        for key, fields, name in (
            ("reset", self._reset_fields, "simreel.ResetRow"),
            ("steps", self._step_fields, "simreel.StepBlock"),
        ):
            sid = m.register_schema(name, SCHEMA_ENCODING, fields_to_schema(fields))
            ids[key] = m.register_channel(TOPICS[key], MESSAGE_ENCODING, sid)
        if self._frames:
            sid = m.register_schema(FRAME_TRANSFORMS_SCHEMA[0], "protobuf", FRAME_TRANSFORMS_SCHEMA[1])
            ids["tf"] = m.register_channel(TOPICS["tf"], "protobuf", sid)
            sid = m.register_schema(SCENE_UPDATE_SCHEMA[0], "protobuf", SCENE_UPDATE_SCHEMA[1])
            ids["scene"] = m.register_channel(TOPICS["scene"], "protobuf", sid)
            sid = m.register_schema(*ROBOT_DESCRIPTION_SCHEMA)
            ids["robot_description"] = m.register_channel(TOPICS["robot_description"], "cdr", sid)
        sid = m.register_schema("simreel.StepScalars", "jsonschema", json.dumps(self._plots_schema()).encode())
        ids["plots"] = m.register_channel(TOPICS["plots"], "json", sid)
        sid = m.register_schema(LOG_SCHEMA[0], "protobuf", LOG_SCHEMA[1])
        ids["log"] = m.register_channel(TOPICS["log"], "protobuf", sid)
        return ids

    def _plots_schema(self) -> dict[str, Any]:
        number = {"type": ["number", "null"]}  # `_json_column` writes NaN and infinities as null
        kinds = {"b": {"type": "boolean"}, "i": {"type": "integer"}, "u": {"type": "integer"}}
        info = {k: kinds.get(np.dtype(s.dtype).kind, number) for k, s in self.meta.info_layout.items()}
        props: dict[str, Any] = {
            "episode": {"type": "integer"},
            "step": {"type": "integer"},
            "reward": number,
            **{f: {"type": "boolean"} for f in FLAG_FIELDS},
            "info": {"type": "object", "properties": info},
            "action": {"type": "array", "items": number},
        }
        return {"title": "simreel.StepScalars", "type": "object", "properties": props}

    def _record(self, record: Any) -> None:
        self._mcap.add_metadata(record_name(record), seal(record.to_metadata()))

    def _log(self, time_ns: int, level: int, text: str) -> None:
        self._mcap.add_message(self._ids["log"], time_ns, encode_log(time_ns, level, text, "simreel"), time_ns)

    # ---------------------------------------------------------------- episodes
    def begin(self, lane: EpisodeLane, meta: EpisodeMeta, reset: dict[str, np.ndarray]) -> None:
        """The episode's begin record, its reset row (exact data and transforms) and a log line."""
        t0 = lane.start_ns
        self._record(EpisodeBeginRecord(meta.index, meta.env_idx, t0, meta.seed))
        self._write_scene(lane.env, t0)
        data = pack_block(self._reset_fields, reset, episode=meta.index, first_row=0, rows=1)
        self._mcap.add_message(self._ids["reset"], t0, data, t0, 0)
        self._transforms(lane, reset, 0, 1)
        self._log(t0, LOG_INFO, f"episode {meta.index} begins (env {meta.env_idx}, seed {meta.seed})")
        self._fh.flush()

    def steps(self, lane: EpisodeLane, arrays: dict[str, np.ndarray], rows: int) -> None:
        """A block of `rows` steps after the lane's current row: exact data, transforms and plot scalars."""
        first = lane.rows
        data = pack_block(self._step_fields, arrays, episode=lane.index, first_row=first, rows=rows)
        t1 = self.time(lane, first + 1)
        self._mcap.add_message(self._ids["steps"], t1, data, t1, first)
        self._transforms(lane, arrays, first + 1, rows)
        self._plots(lane, arrays, first, rows)
        lane.rows += rows

    def commit(self, lane: EpisodeLane, meta: EpisodeMeta) -> int:
        """Close the chunk, then write the episode's record and flush: from here on a kill cannot lose it.
        Returns the time of its last row."""
        end = self.time(lane, lane.rows)
        success = "" if meta.success is None else f", success {meta.success}"
        self._log(end, LOG_INFO, f"episode {meta.index} committed: {lane.rows} steps{success}")
        self._mcap.flush()  # closes the chunk: the episode's messages are in the file before its record
        self._record(EpisodeRecord(meta, lane.start_ns, end, lane.rows))
        self._fh.flush()
        if self._fsync:
            os.fsync(self._fh.fileno())
        return end

    def discard(self, lane: EpisodeLane) -> int:
        """Log the episode as discarded and write its discard record; returns the time of its last row."""
        end = self.time(lane, lane.rows)
        self._log(end, LOG_WARNING, f"episode {lane.index} discarded after {lane.rows} steps")
        self._record(EpisodeDiscardRecord(lane.index, lane.rows))
        self._fh.flush()
        return end

    # ---------------------------------------------------------------- viewable channels
    def scene(self, geometry: SceneGeometry) -> None:
        """Keep sub-scene `geometry.env_idx`'s geometry until its next episode begins (`begin` writes it then)."""
        self._scenes[geometry.env_idx] = geometry

    def _prefix(self, env: int) -> str:
        return f"env{env}/" if self.meta.num_envs > 1 else ""

    def _write_scene(self, env: int, time_ns: int) -> None:
        """Sub-scene `env`'s geometry given since its last episode began, unless it is what was written last."""
        geometry = self._scenes.pop(env, None)
        if geometry is None or not self._frames:
            return
        before = self._scene_written.get(env, (b"", ()))
        messages = scene_messages(geometry, self._frames, prefix=self._prefix(env), world=WORLD_FRAME,
                                  replaced=before[1])
        if messages.scene_update == before[0]:
            return
        self._scene_written[env] = (messages.scene_update, messages.entity_ids)
        self._mcap.add_message(self._ids["scene"], time_ns, messages.scene_update, time_ns)
        self._mcap.add_message(self._ids["robot_description"], time_ns, encode_ros2_string(messages.urdf), time_ns)

    def _poses(self, lane: EpisodeLane, arrays: dict[str, np.ndarray]) -> np.ndarray:
        if self._pose_sources is None:
            return np.asarray(arrays["body_poses"])
        return np.stack([np.asarray(arrays[f"env_states/{p}"])[:, :7] for p in self._pose_sources], axis=1)

    def _transforms(self, lane: EpisodeLane, arrays: dict[str, np.ndarray], first_row: int, rows: int) -> None:
        if not self._frames:
            return
        encoder = self._encoders.get(lane.env)
        if encoder is None:
            prefix = self._prefix(lane.env)
            encoder = FrameTransformsEncoder([WORLD_FRAME] * len(self._frames), [prefix + n for n in self._frames])
            self._encoders[lane.env] = encoder
        times = [self.time(lane, first_row + j) for j in range(rows)]
        for j, msg in enumerate(encoder.encode(self._poses(lane, arrays), times)):
            self._mcap.add_message(self._ids["tf"], times[j], msg, times[j], first_row + j)

    def _plots(self, lane: EpisodeLane, arrays: dict[str, np.ndarray], first: int, rows: int) -> None:
        rewards = _json_column(arrays["rewards"]) if "rewards" in arrays else [None] * rows
        actions = _json_column(arrays["actions"])
        flags = {f: np.asarray(arrays[f], bool).tolist() for f in FLAG_FIELDS if f in arrays}
        info = {k: _json_column(arrays[f"info/{k}"]) for k in self.meta.info_layout}
        for j in range(rows):
            row = {
                "episode": lane.index,
                "step": first + j,
                "reward": rewards[j],
                **{f: col[j] for f, col in flags.items()},
                "info": {k: col[j] for k, col in info.items()},
                "action": actions[j],
            }
            t = self.time(lane, first + j + 1)
            self._mcap.add_message(self._ids["plots"], t, json.dumps(row).encode(), t, first + j)
