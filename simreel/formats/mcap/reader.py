"""`McapReader`: reads simreel's MCAP recordings, complete ones through their summary, killed or damaged ones front
to back.

Only the chunks inside an episode's time span are read and decompressed; the exact arrays come from the
data channels (`simreel.formats.mcap.blocks`), never from the viewable ones. Every check MCAP offers is made:
the summary's CRC when the file is opened, each chunk's CRC when it is read (a chunk that fails it makes its
episode's read fail, naming it), each simreel record's own CRC (`simreel.formats.mcap.records.unseal`), and the
data section's CRC on request (`check_data_crc`, which reads the whole file). A damaged simreel record is
listed in `damaged`, the other episodes stay readable. Reading front to back (`recover=True`) skips a damaged
record, finds the next whole one and keeps going (`skipped` says which bytes were lost).
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeReader, EpisodeRows, block_rows, not_a_file
from simreel.formats.mcap.blocks import (
    fields_from_schema,
    reset_fields,
    step_fields,
    unpack_block,
    unpack_header,
)
from simreel.formats.mcap.records import (
    MCAP_MAGIC,
    EpisodeBeginRecord,
    EpisodeDiscardRecord,
    EpisodeRecord,
    RecordingRecord,
    record_kind,
    unseal,
)
from simreel.io.lock import lock_file
from simreel.io.paths import open_for_reading
from simreel.io.staging import replacement_note
from simreel.model.blocks import StepBlock
from simreel.model.fields import episode_fields
from simreel.model.meta import EpisodeMeta

__all__ = ["McapReader", "McapRows"]

_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_METADATA, _OP_DATA_END, _OP_FOOTER = 0x06, 0x07, 0x0C, 0x0F, 0x02
_RECORD_HEADER = struct.Struct("<BQ")
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4
"""A footer record: opcode, length, summary start, summary offset start, summary CRC."""
_RESYNC_WINDOW = 64 << 20
"""How far past a damaged record the front-to-back reader looks for the next whole one."""


@dataclass(frozen=True)
class _Span:
    start_ns: int
    end_ns: int
    steps: int


@dataclass(frozen=True)
class _ChunkRef:
    offset: int
    """File offset of the chunk record (its opcode byte)."""
    start_ns: int
    end_ns: int


def _has_footer(fh: IO[bytes], size: int) -> bool:
    if size < 2 * len(MCAP_MAGIC) + 9:
        return False
    fh.seek(size - len(MCAP_MAGIC))
    return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def _read_chunk(fh: IO[bytes], offset: int) -> Any:
    """The chunk record at `offset`, its CRC checked (`McapError` / `ValueError` ... when it is damaged)."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk
    from mcap.stream_reader import get_chunk_data_stream

    fh.seek(offset + 9)
    chunk = Chunk.read(ReadDataStream(fh))
    get_chunk_data_stream(chunk, validate_crc=True)  # decompresses and checks the CRC
    return chunk


def _read_metadata(data: bytes) -> Any:
    from mcap.data_stream import ReadDataStream
    from mcap.records import Metadata

    return Metadata.read(ReadDataStream(io.BytesIO(data)))


class McapReader(EpisodeReader):
    """Reads a simreel MCAP recording. Raises `RecordingFileError` for anything else.

    Args:
        path: the .mcap file.
        recover: read a file without summary/footer (a killed recording), or whose summary is damaged, front to
            back instead of refusing it; `recovered` then says so, and `unfinished`, `skipped`, `lost_bytes` what
            was lost.
    """

    def __init__(self, path: str | Path, *, recover: bool = False) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise not_a_file(self.path)
        self._fh: IO[bytes] = open_for_reading(self.path)
        try:
            self._open(recover)
        except BaseException:
            self._fh.close()
            raise

    def _open(self, recover: bool) -> None:
        fh = self._fh
        size = os.fstat(fh.fileno()).st_size
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise RecordingFileError(self.path, "not an MCAP file")
        self.recovered = False
        """True when the file was read front to back (`recover=True`: no footer, or a damaged summary)."""
        self.lost_bytes = 0
        """Bytes at the end of a recovered file that do not form a whole record (cut mid-write)."""
        self.skipped: list[str] = []
        """Damaged stretches of a recovered file that were skipped (a chunk or record failing its check)."""
        self.damaged: list[str] = []
        note = replacement_note(self.path)
        self.notes = [note] if note else []
        if _has_footer(fh, size):
            try:
                chunks, records = self._read_summary(size)
            except RecordingFileError:
                if not recover:
                    raise
                chunks, records, self.lost_bytes = self._scan(size)
                self.recovered = True
        elif not lock_file(fh, exclusive=False):
            raise RecordingFileError(
                self.path, "still being written by a running recording (no footer yet); read it once that process ends"
            )
        elif recover:
            chunks, records, self.lost_bytes = self._scan(size)
            self.recovered = True
        else:
            raise RecordingFileError(
                self.path,
                "truncated MCAP file (no footer): the recording was interrupted or the file was cut; "
                f"run `simreel recover {self.path}` to rescue its committed episodes",
            )
        self._chunks = sorted(chunks, key=lambda c: c.offset)
        self._parse_records(records)

    # ---------------------------------------------------------------- complete files: the summary
    def _read_summary(self, size: int) -> tuple[list[_ChunkRef], list[Any]]:
        """Chunk references and metadata records through the summary, whose CRC is checked first."""
        from mcap.exceptions import McapError
        from mcap.reader import SeekingReader

        self._check_summary_crc(size)
        try:
            self._fh.seek(0)
            summary = SeekingReader(self._fh).get_summary()
        except (McapError, ValueError, EOFError, struct.error, KeyError) as e:
            raise self._corrupt(f"{type(e).__name__}: {e}") from None
        if summary is None:
            return [], []
        chunks = [_ChunkRef(c.chunk_start_offset, c.message_start_time, c.message_end_time)
                  for c in summary.chunk_indexes]
        records = []
        for index in summary.metadata_indexes:
            try:
                records.append(self._indexed_metadata(index))
            except (McapError, ValueError, EOFError, struct.error, UnicodeDecodeError) as e:
                self.damaged.append(f"record {index.name} at byte {index.offset} cannot be read "
                                    f"({str(e) or type(e).__name__})")
        return chunks, records

    def _indexed_metadata(self, index: Any) -> Any:
        """The metadata record a summary's index points at, checked to be the one it names."""
        opcode, length = _RECORD_HEADER.unpack(self._read_at(index.offset, 9))
        if opcode != _OP_METADATA or 9 + length != index.length:
            raise ValueError("no metadata record where the summary's index points")
        record = _read_metadata(self._read_at(index.offset + 9, length))
        if record.name != index.name:
            raise ValueError(f"the record there is named {record.name!r}")
        return record

    def _check_summary_crc(self, size: int) -> None:
        footer_at = size - len(MCAP_MAGIC) - _FOOTER_BYTES
        if footer_at < len(MCAP_MAGIC):
            raise self._corrupt("too short for its footer")
        opcode, _, summary_start, _, crc = struct.unpack("<BQQQI", self._read_at(footer_at, _FOOTER_BYTES))
        if opcode != _OP_FOOTER or summary_start > footer_at:
            raise self._corrupt("its footer is damaged")
        if crc == 0 or summary_start == 0:
            return
        self._fh.seek(summary_start)
        covered = self._fh.read(footer_at - summary_start + _FOOTER_BYTES - 4)
        if zlib.crc32(covered) != crc:
            raise self._corrupt("its summary does not match its CRC")

    def _corrupt(self, problem: str) -> RecordingFileError:
        return RecordingFileError(self.path, f"corrupt MCAP file ({problem}); `simreel recover {self.path} -o OUT` "
                                             "copies the episodes that are intact")

    def check_data_crc(self) -> str | None:
        """Check the data section against the CRC the writer put in its DataEnd record (reads the whole file).
        Returns what is wrong, or None when it matches or the file has none (written by an earlier simreel)."""
        size = os.fstat(self._fh.fileno()).st_size
        footer_at = size - len(MCAP_MAGIC) - _FOOTER_BYTES
        _, _, summary_start, _, _ = struct.unpack("<BQQQI", self._read_at(footer_at, _FOOTER_BYTES))
        end = (summary_start or footer_at) - 13  # the DataEnd record
        header = self._read_at(end, 13) if len(MCAP_MAGIC) <= end else b""
        if len(header) != 13 or header[0] != _OP_DATA_END:
            return "its data section has no end record"
        _, _, stored = struct.unpack("<BQI", header)
        if stored == 0:
            return None
        self._fh.seek(0)
        crc, left = 0, end
        while left:
            block = self._fh.read(min(left, 1 << 20))
            crc, left = zlib.crc32(block, crc), left - len(block)
        return None if crc == stored else "its data section does not match its CRC: some bytes are damaged"

    # ---------------------------------------------------------------- killed or damaged files: front to back
    def _scan(self, size: int) -> tuple[list[_ChunkRef], list[Any], int]:
        """Walk the records from the start; skip a damaged one (naming the bytes) and go on from the next whole
        record; stop at the end of the data section or at a record cut short by the end of the file."""
        pos = len(MCAP_MAGIC)
        chunks: list[_ChunkRef] = []
        records: list[Any] = []
        while pos + 9 <= size:
            opcode, length = _RECORD_HEADER.unpack(self._read_at(pos, 9))
            if opcode in (_OP_DATA_END, _OP_FOOTER) and self._whole(pos, size):
                return chunks, records, 0
            end = pos + 9 + length
            item = self._record_at(pos, opcode, length) if end <= size else None
            if item is not None:
                if isinstance(item, _ChunkRef):
                    chunks.append(item)
                elif item is not True:
                    records.append(item)
                pos = end
                continue
            following = self._resync(pos + 1, size)
            if following is None:
                return chunks, records, size - pos  # a record cut short by the end of the file
            self.skipped.append(f"bytes {pos}–{following - 1} (a damaged record)")
            pos = following
        return chunks, records, size - pos

    def _read_at(self, pos: int, n: int) -> bytes:
        self._fh.seek(pos)
        return self._fh.read(n)

    def _whole(self, pos: int, size: int) -> bool:
        _, length = _RECORD_HEADER.unpack(self._read_at(pos, 9))
        return pos + 9 + length <= size

    def _record_at(self, pos: int, opcode: int, length: int) -> Any:
        """The record at `pos` when it is whole and passes its checks: a `_ChunkRef`, a metadata record, or True
        for a record this reader does not need; None when it is damaged."""
        from mcap.exceptions import McapError

        try:
            if opcode == _OP_CHUNK:
                chunk = _read_chunk(self._fh, pos)
                return _ChunkRef(pos, chunk.message_start_time, chunk.message_end_time)
            if opcode == _OP_METADATA:
                record = _read_metadata(self._read_at(pos + 9, length))
                unseal(record.metadata)
                return record
        except (McapError, Exception):  # noqa: BLE001 - zstd/lz4/CRC/struct errors: any of them means a damaged record
            return None
        return True if opcode in (0x01, 0x03, 0x04, _OP_MESSAGE_INDEX) else None

    def _resync(self, start: int, size: int) -> int | None:
        """The offset of the next whole record after a damaged one (one that passes its checks and is followed
        by another record or the end of the data), or None when none follows."""
        window = self._read_at(start, min(size - start, _RESYNC_WINDOW))
        for k, byte in enumerate(window):
            if byte not in (_OP_CHUNK, _OP_METADATA, _OP_DATA_END) or k + 9 > len(window):
                continue
            pos = start + k
            opcode, length = _RECORD_HEADER.unpack_from(window, k)
            if pos + 9 + length > size:
                continue
            if opcode == _OP_DATA_END:
                if length == 4:
                    return pos
                continue
            if self._record_at(pos, opcode, length) not in (None, True):
                return pos
        return None

    def _parse_records(self, records: list[Any]) -> None:
        heads = [r for r in records if r.name == RecordingRecord.NAME]
        lost_head = [d for d in self.damaged if d.startswith(f"record {RecordingRecord.NAME} ")]
        if not heads and lost_head:
            raise self._corrupt(f"its simreel metadata: {lost_head[0]}")
        if not heads:
            raise RecordingFileError(
                self.path,
                "an MCAP file without simreel metadata (not recorded by simreel)"
                + (" or cut before it" if self.recovered else ""),
            )
        try:
            self._read_head(unseal(heads[0].metadata))
        except RecordingFileError:
            raise
        except (KeyError, ValueError, TypeError) as e:
            raise RecordingFileError(self.path, f"bad simreel metadata in the MCAP file ({type(e).__name__}: {e})") from None
        begun, discarded = self._read_episode_records(records)
        self.episodes.sort(key=lambda m: m.index)
        running = sorted(set(begun) - set(self._spans) - discarded)
        self.unfinished = [self._describe_running(begun[i]) for i in running]
        """Episodes that had begun but were never committed (the recording process stopped first)."""

    def _read_head(self, d: dict[str, str]) -> None:
        version = RecordingRecord.version_of(d)
        if version > FORMAT_VERSION:
            raise RecordingFileError(
                self.path, f"format version {version} is newer than this simreel reads ({FORMAT_VERSION}); upgrade simreel"
            )
        head = RecordingRecord.from_metadata(d)
        self.meta = head.meta
        self.kind = f"simreel MCAP recording (format {version})"
        self._channel_ids = head.channels
        self._reset_fields = fields_from_schema(head.reset_schema)
        self._step_fields = fields_from_schema(head.step_schema)
        self.fields = episode_fields(self.meta)
        if self._step_fields != step_fields(self.meta) or self._reset_fields != reset_fields(self.meta):
            raise RecordingFileError(self.path, "its data channels' field tables do not match the recording's layout "
                                                "(a damaged or altered file)")

    def _read_episode_records(self, records: list[Any]) -> tuple[dict[int, EpisodeBeginRecord], set[int]]:
        """The episode records; a damaged one is named in `damaged` and the others are read."""
        begun: dict[int, EpisodeBeginRecord] = {}
        discarded: set[int] = set()
        self._spans: dict[int, _Span] = {}
        self.episodes: list[EpisodeMeta] = []
        for r in records:
            kind = record_kind(r.name)
            try:
                d = unseal(r.metadata) if kind != RecordingRecord.NAME else {}
                if kind == EpisodeBeginRecord.NAME:
                    b = EpisodeBeginRecord.from_metadata(d)
                    begun[b.index] = b
                elif kind == EpisodeDiscardRecord.NAME:
                    discarded.add(EpisodeDiscardRecord.from_metadata(d).index)
                elif kind == EpisodeRecord.NAME:
                    e = EpisodeRecord.from_metadata(d)
                    self.episodes.append(e.meta)
                    self._spans[e.meta.index] = _Span(e.start_ns, e.end_ns, e.steps)
            except (KeyError, ValueError, TypeError) as e:
                self.damaged.append(f"record {r.name}: {e}")
        return begun, discarded

    def _describe_running(self, begin: EpisodeBeginRecord) -> str:
        try:
            rows = sum(n for key, n, _ in self._blocks(begin.index, begin.start_ns, None, want_data=False)
                       if key == "steps")
        except ValueError as e:
            return f"episode {begin.index} (env {begin.env_idx}; its steps cannot be read: {e})"
        return f"episode {begin.index} (env {begin.env_idx}, {rows} step(s) in the file)"

    # ---------------------------------------------------------------- data
    def _blocks(
        self, index: int, start_ns: int, end_ns: int | None, *, want_data: bool = True
    ) -> Iterator[tuple[str, int, bytes | None]]:
        """(channel key, rows, message data) of episode `index`'s data messages in the chunks of its span."""
        from mcap.records import Message
        from mcap.stream_reader import breakup_chunk

        wanted = {self._channel_ids["reset"]: "reset", self._channel_ids["steps"]: "steps"}
        for ref in self._chunks:
            if ref.end_ns < start_ns or (end_ns is not None and ref.start_ns > end_ns):
                continue
            self.check_open()  # closed while its episode was being read: a read of the closed file is no corrupt chunk
            try:
                records = breakup_chunk(_read_chunk(self._fh, ref.offset), validate_crc=True)
            except Exception as e:  # noqa: BLE001 - zstd/lz4/CRC/struct errors: any of them means a damaged chunk
                raise ValueError(f"the chunk at byte {ref.offset} is corrupt ({type(e).__name__}: {e})") from None
            for rec in records:
                if isinstance(rec, Message) and rec.channel_id in wanted:
                    ep, _, rows = unpack_header(rec.data)
                    if ep == index:
                        yield wanted[rec.channel_id], rows, rec.data if want_data else None

    def open_episode(self, index: int) -> McapRows:
        """Episode `index`, to be read a block of rows at a time from the chunks of its time span."""
        self.check_open()
        return McapRows(self, self.episode_meta(index), self._spans[index])

    def close(self) -> None:
        self.closed = True
        self._fh.close()


class McapRows(EpisodeRows):
    """An episode of an MCAP recording, read from the chunks of its time span: each chunk is decompressed and checked
    against its CRC when it is read, and the episode's step messages are cut or joined into blocks of the rows asked
    for. `blocks` reads them front to back once and checks, as they come, that the rows follow each other with none
    missing, that there is one reset row, and at the end that the rows add up to what the episode's record says."""

    def __init__(self, reader: McapReader, meta: EpisodeMeta, span: _Span) -> None:
        super().__init__(meta, reader.fields)
        self._reader = reader
        self._span = span
        self._cursor: _RunCursor | None = None

    def _messages(self) -> Iterator[tuple[str, int, bytes | None]]:
        self._reader.check_open()
        span = self._span
        return self._reader._blocks(self.meta.index, span.start_ns, span.end_ns)

    def _error(self, problem: object) -> RecordingFileError:
        return RecordingFileError(self._reader.path, f"episode {self.meta.index}: {problem}")

    def reset(self) -> StepBlock:
        try:
            data = next((data for key, _, data in self._messages() if key == "reset"), None)
            if data is None:
                raise ValueError("0 reset rows, expected 1")
            return StepBlock.of(_native(unpack_block(self._reader._reset_fields, data)[2]))
        except ValueError as e:
            raise self._error(e) from None

    def _runs(self) -> Iterator[tuple[int, int, dict[str, np.ndarray]]]:
        """(first step, rows, arrays) of every step message in order, checked as described in the class."""
        row = resets = 0
        try:
            for key, _, data in self._messages():
                if key == "reset":
                    resets += 1
                    continue
                first, rows, arrays = unpack_block(self._reader._step_fields, data)
                if first != row:
                    raise ValueError(f"steps {row}–{first - 1} are missing" if first > row else
                                     f"steps {first}–{first + rows - 1} appear again or out of order")
                yield first, rows, arrays
                row += rows
            if resets != 1:
                raise ValueError(f"{resets} reset rows, expected 1")
            if row != self._span.steps:
                raise ValueError(f"{row} steps in the file, its record says {self._span.steps}")
        except ValueError as e:
            raise self._error(e) from None

    def blocks(self, rows: int | None = None) -> Iterator[tuple[int, StepBlock]]:
        """As `EpisodeRows.blocks`; each block is checked to come from an open reader, also one cut from rows read
        before the reader was closed (an iterator continued after `close` is refused however its rows lie)."""
        rows = rows or block_rows(self.fields)
        pending: list[dict[str, np.ndarray]] = []
        held = start = 0
        for _, n, arrays in self._runs():
            pending.append(arrays)
            held += n
            while held >= rows:
                self._reader.check_open()
                block, pending = _cut(pending, rows)
                yield start, block
                start, held = start + rows, held - rows
        if held:
            self._reader.check_open()
            yield start, _cut(pending, held)[0]

    def steps(self, start: int, stop: int) -> StepBlock:
        """Steps `start`..`stop - 1`. A call that starts where the one before stopped, or later, reads on from
        there (each message once however the steps are asked for in order); one that starts before reads the
        episode from its start again. Refused once the reader is closed, also where the rows were read before."""
        self._reader.check_open()
        if self._cursor is None or start < self._cursor.row:
            self._cursor = _RunCursor(self._runs())
        block, _ = _cut(self._cursor.take(start, stop), stop - start)
        if block.rows != stop - start:
            raise self._error(f"steps {start}–{stop - 1} asked for, the file holds {self.length}")
        return block


class _RunCursor:
    """An episode's step messages read front to back, the message that reaches past the last rows taken kept for
    the next `take`."""

    def __init__(self, runs: Iterator[tuple[int, int, dict[str, np.ndarray]]]) -> None:
        self._runs = runs
        self._held: tuple[int, int, dict[str, np.ndarray]] | None = None
        self.row = 0
        """The first row a `take` can still give."""

    def take(self, start: int, stop: int) -> list[dict[str, np.ndarray]]:
        """The parts of the messages that hold rows `start`..`stop - 1` (`start` >= `row`), in order."""
        parts = []
        while True:
            if self._held is None:
                self._held = next(self._runs, None)
                if self._held is None:
                    break
            first, n, arrays = self._held
            if first >= stop:
                break
            if first + n > start:
                lo, hi = max(start, first) - first, min(stop, first + n) - first
                parts.append({k: a[lo:hi] for k, a in arrays.items()})
            if first + n > stop:
                break
            self._held, self.row = None, first + n
        if self._held is not None:
            self.row = self._held[0]
        return parts


def _native(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Writable copies in native byte order (a no-op order on little-endian machines), so arrays compare and save like
    the HDF5 ones."""
    return {k: np.array(a, dtype=a.dtype.newbyteorder("=")) for k, a in arrays.items()}


def _cut(parts: list[dict[str, np.ndarray]], rows: int) -> tuple[StepBlock, list[dict[str, np.ndarray]]]:
    """The first `rows` rows of consecutive `parts` as one block (copied, native byte order), and what is left."""
    names = list(parts[0]) if parts else []
    joined = {k: np.concatenate([p[k] for p in parts]) for k in names}
    left = {k: a[rows:] for k, a in joined.items()}
    rest = [left] if names and len(next(iter(left.values()))) else []
    return StepBlock.of(_native({k: a[:rows] for k, a in joined.items()})), rest
