"""`McapWriter`: creates an MCAP recording under its lock and streams episodes into it (layout and crash
safety: `simreel.formats.mcap`). The messages themselves are `simreel.formats.mcap.channels`' job."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import IO, Any

from simreel import __version__
from simreel.errors import StorageError, UsageError
from simreel.formats.base import EpisodeSink, EpisodeWriter
from simreel.formats.mcap.channels import EpisodeLane, McapChannels
from simreel.formats.mcap.records import COMPRESSIONS
from simreel.io.durable import deferred_signals, is_storage_error, storage_error
from simreel.io.staging import RecordingTarget, side_folder
from simreel.model.blocks import StepBlock
from simreel.model.geometry import SceneGeometry
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.options.checks import check_flag, whole_number

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
        """`UsageError` for an option the writer cannot take, before any file is created: ``chunk_size="1M"`` failed
        as a raw TypeError inside mcap's writer, 0 or a negative size wrote one chunk per message, ``fsync="no"``
        counted as yes."""
        if self.compression not in COMPRESSIONS:
            raise UsageError(f"unknown MCAP compression {self.compression!r}; use one of {', '.join(COMPRESSIONS)}")
        object.__setattr__(self, "chunk_size", whole_number(
            "chunk_size", self.chunk_size, "the bytes of messages per chunk, an int >= 1 (default 1 MiB)", minimum=1))
        check_flag("fsync", self.fsync)


class _McapSink(EpisodeSink):
    """One running episode: its lane on the time axis and the channels it writes to."""

    def __init__(self, writer: McapWriter, channels: McapChannels, lane: EpisodeLane) -> None:
        self._writer = writer
        self._channels = channels
        self._lane = lane
        self.index = lane.index

    @property
    def steps(self) -> int:
        return self._lane.rows

    def append(self, block: StepBlock) -> None:
        self._writer._check_usable()
        self.check_running()
        arrays = block.converted().conform(self._writer.fields, episode=self.index)
        if len(block):
            self._writer.guard(lambda: self._channels.steps(self._lane, arrays, len(block)),
                               f"episode {self.index} was not committed")

    def commit(self, meta: EpisodeMeta) -> None:
        self._writer._check_usable()
        meta = self._writer.checked_meta(meta, EpisodeMeta)
        self.check_commit(meta)
        self.ended = True
        with deferred_signals():
            end = self._writer.guard(lambda: self._channels.commit(self._lane, meta),
                                     f"episode {meta.index} was not committed")
        self._writer.lane_ended(self._lane, end)
        self._writer.committed.append(meta)

    def discard(self) -> None:
        if not self.ended and not self._writer._closed:  # a closed file takes no record: the episode is unfinished
            self.ended = True
            end = self._writer.guard(lambda: self._channels.discard(self._lane),
                                     f"episode {self._lane.index} was not committed")
            self._writer.lane_ended(self._lane, end)


class McapWriter(EpisodeWriter):
    """Streams episodes into an MCAP recording; see `simreel.formats.mcap` for channels and time.

    Args:
        path: the .mcap file to write.
        meta: the recording's metadata (layouts, pose bodies, contact channels, control frequency).
        overwrite: replace an existing file instead of refusing; the old one is replaced only by `close`
            (`simreel.io.staging`), and never while another writer holds it.
        options: `McapOptions` fields (compression, chunk_size, fsync).

    If the constructor fails once it has created a file, it removes it; a file it refuses (exists, being
    written) is left untouched. A write the storage refuses (a full disk) stops the writer with one line:
    every episode committed before stays in the file, which then needs `simreel recover` (it has no footer).
    """

    records_poses_by_default = True
    """`/tf` shows every link only when the recording has body poses; without them, only root poses."""
    writes_scene = True
    """`/scene` and `/robot_description` draw the bodies on their `/tf` frames (`simreel.formats.mcap.scene`)."""

    def __init__(self, path: str | Path, meta: RecordingMeta, *, overwrite: bool = False, **options: Any) -> None:
        from mcap.writer import Writer

        super().__init__(path, meta)
        self.options = McapOptions(**options)
        if not hasattr(Writer, "flush"):
            raise UsageError("writing MCAP needs mcap>=1.6 (Writer.flush); upgrade it: pip install -U mcap")
        self._lane_next: dict[int, int] = {}
        self._begun: set[int] = set()
        self.committed: list[EpisodeMeta] = []
        self._closed = self._aborted = False
        self._failed: StorageError | None = None
        self._target = RecordingTarget.claim(self.path, self.side_paths(self.path), overwrite=overwrite)
        try:
            self._fh: IO[bytes] = open(self._target.write_path, "r+b")
            self._mcap = self._start(Writer)
            self._channels = McapChannels(self._mcap, self._fh, meta, fsync=self.options.fsync)
        except BaseException as e:
            self.abort()
            if isinstance(e, OSError):
                raise storage_error(self.path, e) if is_storage_error(e) else UsageError(
                    f"cannot write {self.path}: {e.strerror or e}") from None
            raise

    @property
    def compression(self) -> str:
        return self.options.compression

    @classmethod
    def side_paths(cls, path: Path) -> list[Path]:
        return [side_folder(path)]

    @classmethod
    def option_names(cls) -> list[str]:
        return [f.name for f in fields(McapOptions)]

    @classmethod
    def check_options(cls, **options: Any) -> None:
        McapOptions(**options)

    def _start(self, writer_class: Any) -> Any:
        from mcap.writer import CompressionType, IndexType

        kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        # Every index, message indexes too (16 uncompressed bytes per message): simreel's readers find an episode
        # by its chunks' time span and need none, but the TypeScript reader Foxglove opens a file with refuses a
        # chunk index without them.
        mcap = writer_class(self._fh, chunk_size=self.options.chunk_size, compression=kind[self.options.compression],
                            index_types=IndexType.ALL, enable_data_crcs=True)
        mcap.start(profile="", library=f"simreel {__version__}")
        return mcap

    def begin_episode(self, meta: EpisodeMeta, reset: StepBlock) -> EpisodeSink:
        self._check_usable()
        meta = self.checked_meta(meta, EpisodeMeta)
        if meta.index in self._begun:
            raise UsageError(f"{self.path}: episode {meta.index} was already written; episode indices must be unique")
        arrays = self.reset_arrays(meta, reset)
        lane = EpisodeLane(meta.index, meta.env_idx, self._lane_next.get(meta.env_idx, self._channels.origin_ns))
        self._begun.add(meta.index)
        self._lane_next[meta.env_idx] = lane.start_ns + self._channels.step_ns  # a lane holds one running episode
        self.guard(lambda: self._channels.begin(lane, meta, arrays), f"episode {meta.index} was not committed")
        return _McapSink(self, self._channels, lane)

    def write_scene(self, geometry: SceneGeometry) -> None:
        """Draw sub-scene `geometry.env_idx`'s bodies from its next episode on (`/scene` and `/robot_description`,
        written as that episode begins; nothing when it is the geometry written last)."""
        self._check_usable()
        self._channels.scene(geometry)

    def lane_ended(self, lane: EpisodeLane, end_ns: int) -> None:
        """An episode of env `lane.env` ended at `end_ns`: that env's next episode starts one period later."""
        self._lane_next[lane.env] = end_ns + self._channels.step_ns

    def close(self, *, replace: bool = True) -> None:
        """Write the summary and footer, close the file, and move a staged recording over the old one (unless not
        `replace`). After a failed write the file is closed as it is (committed episodes, no footer) and replaces
        nothing."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._failed is None:
                with deferred_signals():
                    self._finish()
        finally:
            self._close_file()
            if self._failed is None:
                self._target.publish(replace=replace)
            else:
                self._target.release()

    def _finish(self) -> None:
        try:
            self._mcap.finish()
        except OSError as e:
            if not is_storage_error(e):
                raise
            self._failed = storage_error(self.path, e, committed=len(self.committed), lost="the file has no footer",
                                         readable=self._where_readable)
            raise self._failed from None

    @property
    def _where_readable(self) -> str:
        where = self._target.write_path
        kept = " (the recording it was to replace is unchanged)" if self._target.staged else ""
        return f" through `simreel recover {where}`{kept}"

    def abort(self) -> None:
        """Drop the recording: a new file is removed, a staged one too (the old recording stays)."""
        if self._aborted:
            return
        self._aborted = self._closed = True
        try:
            if getattr(self, "_fh", None) is not None:
                self._fh.close()
        except OSError:
            pass  # the file is dropped anyway
        self._target.abandon()

    def _close_file(self) -> None:
        try:
            self._fh.close()
        except OSError as e:  # its buffer could not be written out: after a failed write, expected
            if self._failed is None:
                self._failed = storage_error(self.path, e, committed=len(self.committed),
                                             lost="the file has no footer", readable=self._where_readable)
                raise self._failed from None
