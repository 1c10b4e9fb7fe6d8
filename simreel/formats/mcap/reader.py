"""`McapReader`: reads simreel's MCAP recordings, complete ones through their summary, killed ones front to back.

Only the chunks inside an episode's time span are read and decompressed; the exact arrays come from the
data channels (`simreel.formats.mcap.blocks`), never from the viewable ones.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.episode import Episode, EpisodeMeta
from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeReader
from simreel.formats.mcap.blocks import WireField, fields_from_schema, unpack_block, unpack_header
from simreel.formats.mcap.lock import lock_file
from simreel.formats.mcap.records import (
    MCAP_MAGIC,
    EpisodeBeginRecord,
    EpisodeDiscardRecord,
    EpisodeRecord,
    RecordingRecord,
    record_kind,
)

__all__ = ["McapReader"]

_OP_CHUNK, _OP_METADATA, _OP_DATA_END, _OP_FOOTER = 0x06, 0x0C, 0x0F, 0x02


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


class McapReader(EpisodeReader):
    """Reads a simreel MCAP recording. Raises `RecordingFileError` for anything else.

    Args:
        path: the .mcap file.
        recover: read a file without summary/footer (a killed recording) front to back instead of
            refusing it; `recovered` then says so, and `unfinished` / `lost_bytes` what was lost.
    """

    def __init__(self, path: str | Path, *, recover: bool = False) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingFileError(self.path, "no such file")
        self._fh: IO[bytes] = open(self.path, "rb")
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
        """True when the file had no footer and was read front to back (`recover=True`)."""
        self.lost_bytes = 0
        """Bytes at the end of a recovered file that do not form a whole record (cut mid-write)."""
        if _has_footer(fh, size):
            chunks, records = self._read_summary()
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

    def _read_summary(self) -> tuple[list[_ChunkRef], list[Any]]:
        from mcap.exceptions import McapError
        from mcap.reader import SeekingReader

        try:
            self._fh.seek(0)
            reader = SeekingReader(self._fh)
            summary = reader.get_summary()
            records = list(reader.iter_metadata())
        except (McapError, ValueError, EOFError, struct.error, KeyError) as e:
            raise RecordingFileError(self.path, f"corrupt MCAP file ({type(e).__name__}: {e})") from None
        if summary is None:
            chunks: list[_ChunkRef] = []
        else:
            chunks = [_ChunkRef(c.chunk_start_offset, c.message_start_time, c.message_end_time)
                      for c in summary.chunk_indexes]
        return chunks, records

    def _scan(self, size: int) -> tuple[list[_ChunkRef], list[Any], int]:
        """Walk the records of a file without footer; stop at the first one cut short."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Metadata

        fh = self._fh
        pos = len(MCAP_MAGIC)
        chunks: list[_ChunkRef] = []
        records: list[Any] = []
        while pos + 9 <= size:
            fh.seek(pos)
            opcode, length = struct.unpack("<BQ", fh.read(9))
            if pos + 9 + length > size:
                break
            if opcode == _OP_CHUNK:
                start, end = struct.unpack("<QQ", fh.read(16))
                chunks.append(_ChunkRef(pos, start, end))
            elif opcode == _OP_METADATA:
                try:
                    records.append(Metadata.read(ReadDataStream(io.BytesIO(fh.read(length)))))
                except (ValueError, EOFError, struct.error, UnicodeDecodeError):
                    break
            elif opcode in (_OP_DATA_END, _OP_FOOTER):
                return chunks, records, 0
            pos += 9 + length
        return chunks, records, size - pos

    def _parse_records(self, records: list[Any]) -> None:
        heads = [r for r in records if r.name == RecordingRecord.NAME]
        if not heads:
            raise RecordingFileError(
                self.path,
                "an MCAP file without simreel metadata (not recorded by simreel)"
                + (" or cut before it" if self.recovered else ""),
            )
        try:
            self._read_head(heads[0].metadata)
            begun, discarded = self._read_episode_records(records)
        except RecordingFileError:
            raise
        except (KeyError, ValueError, TypeError) as e:
            raise RecordingFileError(self.path, f"bad simreel metadata in the MCAP file ({type(e).__name__}: {e})") from None
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

    def _read_episode_records(self, records: list[Any]) -> tuple[dict[int, EpisodeBeginRecord], set[int]]:
        begun: dict[int, EpisodeBeginRecord] = {}
        discarded: set[int] = set()
        self._spans: dict[int, _Span] = {}
        self.episodes: list[EpisodeMeta] = []
        for r in records:
            kind = record_kind(r.name)
            if kind == EpisodeBeginRecord.NAME:
                b = EpisodeBeginRecord.from_metadata(r.metadata)
                begun[b.index] = b
            elif kind == EpisodeDiscardRecord.NAME:
                discarded.add(EpisodeDiscardRecord.from_metadata(r.metadata).index)
            elif kind == EpisodeRecord.NAME:
                e = EpisodeRecord.from_metadata(r.metadata)
                self.episodes.append(e.meta)
                self._spans[e.meta.index] = _Span(e.start_ns, e.end_ns, e.steps)
        return begun, discarded

    def _describe_running(self, begin: EpisodeBeginRecord) -> str:
        rows = sum(n for key, n, _ in self._blocks(begin.index, begin.start_ns, None, want_data=False) if key == "steps")
        return f"episode {begin.index} (env {begin.env_idx}, {rows} step(s) in the file)"

    # ---------------------------------------------------------------- data
    def _blocks(
        self, index: int, start_ns: int, end_ns: int | None, *, want_data: bool = True
    ) -> Iterator[tuple[str, int, bytes | None]]:
        """(channel key, rows, message data) of episode `index`'s data messages in the chunks of its span."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Chunk, Message
        from mcap.stream_reader import breakup_chunk

        wanted = {self._channel_ids["reset"]: "reset", self._channel_ids["steps"]: "steps"}
        for ref in self._chunks:
            if ref.end_ns < start_ns or (end_ns is not None and ref.start_ns > end_ns):
                continue
            try:
                self._fh.seek(ref.offset + 9)
                records = breakup_chunk(Chunk.read(ReadDataStream(self._fh)))
            except Exception as e:  # zstd/lz4/struct errors: any of them means a damaged chunk
                raise RecordingFileError(
                    self.path, f"corrupt chunk at byte {ref.offset} ({type(e).__name__}: {e})"
                ) from None
            for rec in records:
                if isinstance(rec, Message) and rec.channel_id in wanted:
                    ep, _, rows = unpack_header(rec.data)
                    if ep == index:
                        yield wanted[rec.channel_id], rows, rec.data if want_data else None

    def read_episode(self, index: int) -> Episode:
        meta = self.episode_meta(index)
        span = self._spans[index]
        resets: list[bytes] = []
        steps: dict[int, dict[str, np.ndarray]] = {}
        try:
            for key, _, data in self._blocks(index, span.start_ns, span.end_ns):
                if key == "reset":
                    resets.append(data)
                else:
                    first, _, arrays = unpack_block(self._step_fields, data)
                    steps[first] = arrays
            if len(resets) != 1:
                raise ValueError(f"{len(resets)} reset rows, expected 1")
            _, _, row0 = unpack_block(self._reset_fields, resets[0])
        except ValueError as e:
            raise RecordingFileError(self.path, f"episode {index}: {e}") from None
        blocks = []
        row = 0
        for first in sorted(steps):
            if first != row:
                raise RecordingFileError(self.path, f"episode {index}: steps {row}–{first - 1} are missing")
            blocks.append(steps[first])
            row += len(steps[first]["actions"])
        if row != span.steps:
            raise RecordingFileError(self.path, f"episode {index}: {row} steps in the file, its record says {span.steps}")
        return self._assemble(meta, row0, blocks)

    def _assemble(self, meta: EpisodeMeta, row0: dict[str, np.ndarray], blocks: list[dict[str, np.ndarray]]) -> Episode:
        def steps_of(f: WireField) -> np.ndarray:
            if not blocks:
                return np.empty((0, *f.shape), f.dtype)
            return np.concatenate([b[f.name] for b in blocks])

        cols = {f.name: steps_of(f) for f in self._step_fields}
        for f in self._reset_fields:
            cols[f.name] = np.concatenate([row0[f.name], cols[f.name]])
        # Native byte order (a no-op on little-endian machines) so arrays compare and save like the HDF5 ones.
        cols = {k: v.astype(v.dtype.newbyteorder("="), copy=False) for k, v in cols.items()}
        return Episode.from_fields(meta, cols)

    def close(self) -> None:
        self._fh.close()
