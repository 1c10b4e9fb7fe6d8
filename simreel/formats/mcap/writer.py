"""`McapWriter`: creates an MCAP recording under its lock and streams episodes into it (layout and crash
safety: `simreel.formats.mcap`). The messages themselves are `simreel.formats.mcap.channels`' job."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from simreel import __version__
from simreel.episode import EpisodeMeta, RecordingMeta, StepBlock
from simreel.errors import UsageError
from simreel.formats.base import EpisodeSink, EpisodeWriter
from simreel.formats.mcap.channels import EpisodeLane, McapChannels
from simreel.formats.mcap.lock import being_written, lock_file
from simreel.formats.mcap.records import COMPRESSIONS

__all__ = ["McapWriter", "McapOptions"]


@dataclass(frozen=True)
class McapOptions:
    """How an MCAP recording is written.

    Attributes:
        compression: chunk compression, "zstd" (default), "lz4" or "none".
        chunk_size: bytes of messages gathered before a chunk is compressed and written; a commit also
            closes the current chunk so the episode is on disk.
        fsync: also `os.fsync` at each commit (survives power loss, not only a killed process).
    """

    compression: str = "zstd"
    chunk_size: int = 1 << 20
    fsync: bool = False

    def __post_init__(self) -> None:
        if self.compression not in COMPRESSIONS:
            raise UsageError(f"unknown MCAP compression {self.compression!r}; use one of {', '.join(COMPRESSIONS)}")


class _McapSink(EpisodeSink):
    """One running episode: its lane on the time axis and the channels it writes to."""

    def __init__(self, writer: McapWriter, channels: McapChannels, lane: EpisodeLane) -> None:
        self._writer = writer
        self._channels = channels
        self._lane = lane
        self._open = True

    def _check_open(self) -> None:
        if not self._open:
            raise UsageError(f"episode {self._lane.index} was already committed or discarded")

    def append(self, block: StepBlock) -> None:
        self._check_open()
        if len(block):
            self._channels.steps(self._lane, block.conform(self._writer.fields, episode=self._lane.index), len(block))

    def commit(self, meta: EpisodeMeta) -> None:
        self._check_open()
        if meta.index != self._lane.index:
            raise UsageError(f"commit of episode {meta.index} on the sink of episode {self._lane.index}")
        self._open = False
        self._writer.lane_ended(self._lane, self._channels.commit(self._lane, meta))
        self._writer.committed.append(meta)

    def discard(self) -> None:
        if self._open:
            self._open = False
            self._writer.lane_ended(self._lane, self._channels.discard(self._lane))


class McapWriter(EpisodeWriter):
    """Streams episodes into an MCAP recording; see `simreel.formats.mcap` for channels and time.

    Args:
        path: the .mcap file to write.
        meta: the recording's metadata (layouts, pose bodies, contact channels, control frequency).
        overwrite: replace an existing file instead of refusing.
        options: `McapOptions` fields (compression, chunk_size, fsync).

    If the constructor fails once it has created (or, with `overwrite`, emptied) the file, it closes and
    removes it; a file it refuses (exists, being written) is left untouched.
    """

    records_poses_by_default = True
    """`/tf` shows every link only when the recording has body poses; without them, only root poses."""

    def __init__(self, path: str | Path, meta: RecordingMeta, *, overwrite: bool = False, **options: Any) -> None:
        from mcap.writer import Writer

        super().__init__(path, meta)
        self.options = McapOptions(**options)
        if not hasattr(Writer, "flush"):
            raise UsageError("writing MCAP needs mcap>=1.6 (Writer.flush); upgrade it: pip install -U mcap")
        self._lane_next: dict[int, int] = {}
        self._begun: set[int] = set()
        self.committed: list[EpisodeMeta] = []
        self._closed = False
        self.check_target(self.path, overwrite=overwrite)
        self._fh: IO[bytes] = self._create(overwrite=overwrite)
        try:
            self._mcap = self._start(Writer)
            self._channels = McapChannels(self._mcap, self._fh, meta, fsync=self.options.fsync)
        except BaseException as e:
            self.path.unlink(missing_ok=True)  # while the lock is still held: the file is this writer's
            self._fh.close()
            if isinstance(e, OSError):
                raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
            raise

    @property
    def compression(self) -> str:
        return self.options.compression

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

    def _start(self, writer_class: Any) -> Any:
        from mcap.writer import CompressionType

        kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        mcap = writer_class(self._fh, chunk_size=self.options.chunk_size, compression=kind[self.options.compression])
        mcap.start(profile="", library=f"simreel {__version__}")
        return mcap

    def begin_episode(self, meta: EpisodeMeta, reset: StepBlock) -> EpisodeSink:
        if self._closed:
            raise UsageError(f"{self.path} is closed")
        if meta.index in self._begun:
            raise UsageError(f"{self.path}: episode {meta.index} was already written; episode indices must be unique")
        arrays = reset.conform(self.reset_fields, episode=meta.index)
        lane = EpisodeLane(meta.index, meta.env_idx, self._lane_next.get(meta.env_idx, 0))
        self._begun.add(meta.index)
        self._lane_next[meta.env_idx] = lane.start_ns + self._channels.step_ns  # a lane holds one running episode
        self._channels.begin(lane, meta, arrays)
        return _McapSink(self, self._channels, lane)

    def lane_ended(self, lane: EpisodeLane, end_ns: int) -> None:
        """An episode of env `lane.env` ended at `end_ns`: that env's next episode starts one period later."""
        self._lane_next[lane.env] = end_ns + self._channels.step_ns

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._mcap.finish()
        finally:
            self._fh.close()
