"""Recording formats behind one interface: pick a writer by file suffix, a reader by file content.

`open_writer("x.h5", meta)` / `open_writer("x.mcap", meta)` and `open_reader(path)` are the only entry
points the rooms use; no code outside `simreel.formats` knows how a format lays out its bytes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from simreel.episode import RecordingMeta
from simreel.errors import RecordingFileError, UsageError
from simreel.formats.base import EpisodeReader, EpisodeSink, EpisodeWriter, StepBlock

__all__ = ["open_writer", "open_reader", "format_of", "EpisodeReader", "EpisodeWriter", "EpisodeSink", "StepBlock"]

HDF5_SUFFIXES = (".h5", ".hdf5")
MCAP_SUFFIXES = (".mcap",)
_MCAP_MAGIC = b"\x89MCAP0\r\n"


def format_of(path: str | Path) -> str:
    """"hdf5" or "mcap" from the file suffix; a clear error for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix in HDF5_SUFFIXES:
        return "hdf5"
    if suffix in MCAP_SUFFIXES:
        return "mcap"
    raise UsageError(f"{path}: unknown recording suffix {suffix!r}; use .h5 (HDF5) or .mcap (MCAP)")


def open_writer(path: str | Path, meta: RecordingMeta, **options: Any) -> EpisodeWriter:
    """A writer for `path`, chosen by its suffix (.h5/.hdf5 or .mcap)."""
    if format_of(path) == "hdf5":
        from simreel.formats.hdf5 import Hdf5Writer

        return Hdf5Writer(path, meta, **options)
    from simreel.formats.mcap import McapWriter

    return McapWriter(path, meta, **options)


def open_reader(path: str | Path) -> EpisodeReader:
    """A reader for `path`, chosen by the file's magic bytes, whatever its suffix."""
    p = Path(path)
    if not p.is_file():
        raise RecordingFileError(p, "no such file")
    with open(p, "rb") as fh:
        head = fh.read(8)
    from simreel.formats.hdf5 import HDF5_MAGIC

    if head == HDF5_MAGIC:
        from simreel.formats.hdf5 import Hdf5Reader

        return Hdf5Reader(p)
    if head == _MCAP_MAGIC:
        from simreel.formats.mcap import McapReader

        return McapReader(p)
    if not head:
        raise RecordingFileError(p, "empty file")
    raise RecordingFileError(p, "neither an HDF5 nor an MCAP file")
