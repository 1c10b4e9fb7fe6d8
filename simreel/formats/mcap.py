"""MCAP recordings: exact data for simreel, and channels Foxglove and Rerun show without simreel.

Channels (one schema each)::

    /simreel/reset   simreel.ResetRow    (simreel-fields)  row 0 of state/obs/poses, one message per episode
    /simreel/steps   simreel.StepBlock   (simreel-fields)  every per-step array, one message per block of steps
    /tf              foxglove.FrameTransforms (protobuf)   world pose of every body, one message per row
    /plots           simreel.StepScalars (jsonschema/json) reward, flags, info scalars, action per step
    /log             foxglove.Log        (protobuf)        episode begins / is committed / is discarded

The data channels hold the arrays bit-exactly (see `simreel.formats.mcap_blocks`); the viewable ones
are derived from them. `/tf` shows `Episode.body_poses` (every actor and articulation link, parent frame
`world`, child frame = body name) when the recording has them (`RecordingMeta.pose_bodies`, the default
for `.mcap`); otherwise it shows what the state dict holds: every actor in it and each articulation's root
link. With `num_envs > 1` child frames are `env<i>/<body>` (sub-scenes share the origin).

Metadata records: `simreel` (format version, `RecordingMeta` JSON, field tables, channel ids, time base),
then per episode i `simreel.episode_begin.<i>`, and `simreel.episode.<i>` (its `EpisodeMeta`, time span,
steps) once it is committed, or `simreel.episode_discard.<i>` (one name per record: Rerun merges records
of the same name).

Time: `log_time = episode start + row × step_ns`, with `step_ns = 1e9 / control_freq` (the env's control
period; 1 s if unknown) and row 0 the state after reset. The episodes of one parallel env follow each
other on the time axis (the next starts one period after the last row of the previous), so Foxglove's
and Rerun's timelines play the whole recording; each message's `sequence` is its row (step) index, and
every `/plots` message names its episode. `McapReader.read_episode(i)` reads only the chunks in
episode i's span.

Crash safety: `commit` closes the current chunk, writes the `simreel.episode` metadata record after it
and flushes to the OS, so a `kill -9` after `commit` returns loses nothing of that episode (`fsync=True`
also survives a power cut). An episode exists for simreel only once its record is in the file: a
discarded or never-committed episode's messages stay in the append-only file (viewers show them; `/log`
says so) but the reader skips them. A killed recording has no summary or footer; `McapReader` refuses it
with one line that points to `simreel recover`, which reads it front to back (`McapReader(path,
recover=True)`), rewrites the committed episodes into a complete file and reports what was lost. The
writer holds an advisory lock on the file, so a file still being written is not taken for a killed one.

Modules: this one writes; `mcap_reader` reads; `mcap_blocks` owns the bytes of the data channels,
`mcap_foxglove` the Foxglove messages, `mcap_file` the names both sides share.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import IO, Any

import numpy as np

from simreel import FORMAT_VERSION, __version__
from simreel.episode import FLAG_FIELDS, EpisodeMeta, RecordingMeta
from simreel.errors import EpisodeLayoutError, UsageError
from simreel.formats.base import EpisodeSink, EpisodeWriter, StepBlock, reset_row
from simreel.formats.mcap_blocks import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    fields_to_schema,
    pack_block,
    reset_fields,
    step_fields,
)
from simreel.formats.mcap_file import (
    COMPRESSIONS,
    META_BEGIN,
    META_DISCARD,
    META_EPISODE,
    META_RECORDING,
    TOPICS,
    WORLD_FRAME,
    being_written,
    lock_file,
    step_ns_of,
)
from simreel.formats.mcap_foxglove import (
    FRAME_TRANSFORMS_SCHEMA,
    LOG_INFO,
    LOG_SCHEMA,
    LOG_WARNING,
    FrameTransformsEncoder,
    encode_log,
)
from simreel.formats.mcap_reader import McapReader

__all__ = ["McapWriter", "McapReader", "COMPRESSIONS", "TOPICS", "step_ns_of", "being_written"]


# --------------------------------------------------------------------------------------- view poses
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


def _json_column(a: Any) -> list[Any]:
    """Rows of `a` as JSON values; NaN/inf become null (JSON has no such numbers; the exact values are in
    `/simreel/steps`)."""
    a = np.asarray(a)
    if a.dtype.kind == "f":
        finite = np.isfinite(a)
        a = a.astype(np.float64)
        if not finite.all():
            a = a.astype(object)
            a[~finite] = None
    return a.tolist()


# ------------------------------------------------------------------------------------------- writer
class _McapSink(EpisodeSink):
    def __init__(self, writer: McapWriter, meta: EpisodeMeta, reset: dict[str, np.ndarray]) -> None:
        self._writer = writer
        self._index = meta.index
        self._env = meta.env_idx
        self._start = writer._lane_next.get(meta.env_idx, 0)
        self._rows = 0
        self._open = True
        writer._begin(self, meta, reset)

    def append(self, block: StepBlock) -> None:
        if not self._open:
            raise UsageError(f"episode {self._index} was already committed or discarded")
        if len(block):
            self._writer._append(self, block)
            self._rows += len(block)

    def commit(self, meta: EpisodeMeta) -> None:
        if not self._open:
            raise UsageError(f"episode {self._index} was already committed or discarded")
        if meta.index != self._index:
            raise UsageError(f"commit of episode {meta.index} on the sink of episode {self._index}")
        self._open = False
        self._writer._commit(self, meta)

    def discard(self) -> None:
        if self._open:
            self._open = False
            self._writer._discard(self)


class McapWriter(EpisodeWriter):
    """Streams episodes into an MCAP recording; see the module docstring for channels and time.

    Args:
        path: the .mcap file to write.
        meta: the recording's metadata (layouts, pose bodies, contact channels, control frequency).
        overwrite: replace an existing file instead of refusing.
        compression: chunk compression, "zstd" (default), "lz4" or "none".
        chunk_size: bytes of messages gathered before a chunk is compressed and written; `commit`
            also closes the current chunk so the episode is on disk.
        fsync: also `os.fsync` at each commit (survives power loss, not only a killed process).

    If the constructor fails once it has created (or, with `overwrite`, emptied) the file, it closes and
    removes it; a file it refuses (exists, being written) is left untouched.
    """

    records_poses_by_default = True
    """`/tf` shows every link only when the recording has body poses; without them, only root poses."""

    def __init__(
        self,
        path: str | Path,
        meta: RecordingMeta,
        *,
        overwrite: bool = False,
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
        fsync: bool = False,
    ) -> None:
        from mcap.writer import CompressionType, Writer

        super().__init__(path, meta)
        if compression not in COMPRESSIONS:
            raise UsageError(f"unknown MCAP compression {compression!r}; use one of {', '.join(COMPRESSIONS)}")
        if not hasattr(Writer, "flush"):
            raise UsageError("writing MCAP needs mcap>=1.6 (Writer.flush); upgrade it: pip install -U mcap")
        self.compression = compression
        self._fsync = fsync
        self._step_ns = step_ns_of(meta)
        self._reset_fields = reset_fields(meta)
        self._step_fields = step_fields(meta)
        self._frames, self._pose_sources = _view_frames(meta)
        self._encoders: dict[int, FrameTransformsEncoder] = {}
        self._lane_next: dict[int, int] = {}
        self._begun: set[int] = set()
        self.committed: list[EpisodeMeta] = []
        self._closed = False
        self.check_target(self.path, overwrite=overwrite)
        self._fh: IO[bytes] = self._create(overwrite=overwrite)
        try:
            self._mcap = Writer(
                self._fh,
                chunk_size=chunk_size,
                compression={"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[
                    compression
                ],
            )
            self._mcap.start(profile="", library=f"simreel {__version__}")
            self._channels = self._register_channels()
            self._mcap.add_metadata(META_RECORDING, self._recording_record())
            self._fh.flush()
        except BaseException as e:
            self.path.unlink(missing_ok=True)  # while the lock is still held: the file is this writer's
            self._fh.close()
            if isinstance(e, OSError):
                raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
            raise

    @classmethod
    def check_target(cls, path: Path, *, overwrite: bool) -> None:
        super().check_target(path, overwrite=overwrite)
        if being_written(path):
            raise UsageError(f"{path} is being written by another recording; choose another file")

    def _create(self, *, overwrite: bool) -> IO[bytes]:
        """The file opened for writing under the writer's lock (released by close() or the death of the
        process). An existing file is emptied only once the lock is held, so a recording that another
        process is writing is never truncated; without `overwrite` an existing file is refused."""
        flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_BINARY", 0)
        try:
            try:
                fd = os.open(self.path, flags | os.O_EXCL, 0o666)
            except FileExistsError:
                if not overwrite:
                    raise UsageError(f"{self.path} already exists; pass --overwrite to replace it") from None
                fd = os.open(self.path, flags, 0o666)
        except OSError as e:
            raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
        fh = os.fdopen(fd, "wb")
        if not lock_file(fh, exclusive=True):
            fh.close()
            raise UsageError(f"{self.path} is being written by another recording; choose another file")
        try:
            fh.truncate(0)
        except OSError as e:
            fh.close()
            raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
        return fh

    # ---------------------------------------------------------------- file header
    def _register_channels(self) -> dict[str, int]:
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
        sid = m.register_schema("simreel.StepScalars", "jsonschema", json.dumps(self._plots_schema()).encode())
        ids["plots"] = m.register_channel(TOPICS["plots"], "json", sid)
        sid = m.register_schema(LOG_SCHEMA[0], "protobuf", LOG_SCHEMA[1])
        ids["log"] = m.register_channel(TOPICS["log"], "protobuf", sid)
        return ids

    def _plots_schema(self) -> dict[str, Any]:
        kinds = {"b": "boolean", "i": "integer", "u": "integer", "f": "number"}
        info = {k: {"type": kinds.get(np.dtype(s.dtype).kind, "number")} for k, s in self.meta.info_layout.items()}
        props: dict[str, Any] = {
            "episode": {"type": "integer"},
            "step": {"type": "integer"},
            "reward": {"type": "number"},
            **{f: {"type": "boolean"} for f in FLAG_FIELDS},
            "info": {"type": "object", "properties": info},
            "action": {"type": "array", "items": {"type": "number"}},
        }
        return {"title": "simreel.StepScalars", "type": "object", "properties": props}

    def _recording_record(self) -> dict[str, str]:
        m = self.meta
        return {
            "format_version": str(FORMAT_VERSION),
            "simreel_version": __version__,
            "env_id": m.env_id,
            "control_mode": str(m.control_mode),
            "command": m.command,
            "created_utc": m.created_utc,
            "step_ns": str(self._step_ns),
            "time": "log_time = episode start + row x step_ns; row 0 is the state after reset",
            "pose_source": "recorded body poses" if m.pose_bodies else "state dict (actors, articulation roots)",
            "channels": json.dumps(self._channels),
            "reset_fields": fields_to_schema(self._reset_fields).decode(),
            "step_fields": fields_to_schema(self._step_fields).decode(),
            "recording_meta": json.dumps(m.to_json()),
        }

    # ---------------------------------------------------------------- episodes
    def begin_episode(
        self,
        meta: EpisodeMeta,
        initial_state: dict[str, np.ndarray],
        initial_obs: dict[str, np.ndarray] | None = None,
        initial_poses: np.ndarray | None = None,
    ) -> EpisodeSink:
        if self._closed:
            raise UsageError(f"{self.path} is closed")
        if meta.index in self._begun:
            raise UsageError(f"{self.path}: episode {meta.index} was already written; episode indices must be unique")
        return _McapSink(self, meta, reset_row(initial_state, initial_obs, initial_poses))

    def _time(self, sink: _McapSink, row: int) -> int:
        return sink._start + row * self._step_ns

    def _log(self, time_ns: int, level: int, text: str) -> None:
        self._mcap.add_message(self._channels["log"], time_ns, encode_log(time_ns, level, text, "simreel"), time_ns)

    def _begin(self, sink: _McapSink, meta: EpisodeMeta, reset: dict[str, np.ndarray]) -> None:
        self._begun.add(meta.index)
        self._lane_next[meta.env_idx] = sink._start + self._step_ns  # a lane holds one running episode
        t0 = sink._start
        self._mcap.add_metadata(f"{META_BEGIN}.{meta.index}", {
            "index": str(meta.index), "env_idx": str(meta.env_idx), "start_ns": str(t0), "seed": str(meta.seed),
        })
        data = pack_block(self._reset_fields, reset, episode=meta.index, first_row=0, rows=1)
        self._mcap.add_message(self._channels["reset"], t0, data, t0, 0)
        self._add_transforms(sink, reset, 0, 1)
        self._log(t0, LOG_INFO, f"episode {meta.index} begins (env {meta.env_idx}, seed {meta.seed})")
        self._fh.flush()

    def _append(self, sink: _McapSink, block: StepBlock) -> None:
        k, first = len(block), sink._rows
        data = pack_block(self._step_fields, block, episode=sink._index, first_row=first, rows=k)
        t1 = self._time(sink, first + 1)
        self._mcap.add_message(self._channels["steps"], t1, data, t1, first)
        self._add_transforms(sink, block, first + 1, k)
        self._add_plots(sink, block, first)

    def _add_transforms(self, sink: _McapSink, source: Any, first_row: int, rows: int) -> None:
        if not self._frames:
            return
        if self._pose_sources is None:
            poses = source["body_poses"] if isinstance(source, dict) else source.body_poses
            if poses is None:
                raise EpisodeLayoutError(f"episode {sink._index}: no body_poses, but the recording lists pose bodies")
            poses = np.asarray(poses)
        else:
            states = source if isinstance(source, dict) else {f"env_states/{p}": a for p, a in source.env_states.items()}
            poses = np.stack([np.asarray(states[f"env_states/{p}"])[:, :7] for p in self._pose_sources], axis=1)
        encoder = self._encoders.get(sink._env)
        if encoder is None:
            prefix = f"env{sink._env}/" if self.meta.num_envs > 1 else ""
            encoder = FrameTransformsEncoder([WORLD_FRAME] * len(self._frames), [prefix + n for n in self._frames])
            self._encoders[sink._env] = encoder
        times = [self._time(sink, first_row + j) for j in range(rows)]
        channel = self._channels["tf"]
        for j, msg in enumerate(encoder.encode(poses, times)):
            self._mcap.add_message(channel, times[j], msg, times[j], first_row + j)

    def _add_plots(self, sink: _McapSink, block: StepBlock, first: int) -> None:
        rewards, actions = _json_column(block.rewards), _json_column(block.actions)
        flags = {f: np.asarray(getattr(block, f), bool).tolist() for f in FLAG_FIELDS}
        info = {k: _json_column(block.info[k]) for k in self.meta.info_layout if k in block.info}
        channel, index = self._channels["plots"], sink._index
        for j in range(len(block)):
            row = {
                "episode": index,
                "step": first + j,
                "reward": rewards[j],
                **{f: col[j] for f, col in flags.items()},
                "info": {k: col[j] for k, col in info.items()},
                "action": actions[j],
            }
            t = self._time(sink, first + j + 1)
            self._mcap.add_message(channel, t, json.dumps(row).encode(), t, first + j)

    def _commit(self, sink: _McapSink, meta: EpisodeMeta) -> None:
        end = self._time(sink, sink._rows)
        success = "" if meta.success is None else f", success {meta.success}"
        self._log(end, LOG_INFO, f"episode {meta.index} committed: {sink._rows} steps{success}")
        self._mcap.flush()  # closes the chunk: the episode's messages are in the file before its record
        self._mcap.add_metadata(f"{META_EPISODE}.{meta.index}", {
            "index": str(meta.index),
            "episode": json.dumps(meta.to_json()),
            "start_ns": str(sink._start),
            "end_ns": str(end),
            "steps": str(sink._rows),
        })
        self._fh.flush()
        if self._fsync:
            os.fsync(self._fh.fileno())
        self._lane_next[sink._env] = end + self._step_ns
        self.committed.append(meta)

    def _discard(self, sink: _McapSink) -> None:
        end = self._time(sink, sink._rows)
        self._log(end, LOG_WARNING, f"episode {sink._index} discarded after {sink._rows} steps")
        self._mcap.add_metadata(f"{META_DISCARD}.{sink._index}", {"index": str(sink._index), "steps": str(sink._rows)})
        self._fh.flush()
        self._lane_next[sink._env] = end + self._step_ns

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._mcap.finish()
        finally:
            self._fh.close()
