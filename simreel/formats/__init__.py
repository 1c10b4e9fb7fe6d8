"""Recording formats behind one interface: pick a writer by file suffix, a reader by file content.

Readers: simreel's HDF5 (`hdf5`), simreel's MCAP (`mcap`), and ManiSkill's own trajectory files (`maniskill`:
HDF5 without simreel's metadata, with traj_N groups and a JSON sidecar).

`open_writer("x.h5", meta)` / `open_writer("x.mcap", meta)` and `open_reader(path)` are the only entry
points the rooms use; no code outside `simreel.formats` knows how a format lays out its bytes or which
files it writes beside the recording (`check_writable`, `check_report_writable`, `remove_recording`,
`records_poses_by_default` answer for it).
"""

from simreel.formats.base import EpisodeReader, EpisodeSink, EpisodeWriter
from simreel.formats.registry import (
    HDF5_SUFFIXES,
    MCAP_SUFFIXES,
    check_report_writable,
    check_writable,
    check_writer_options,
    format_of,
    open_reader,
    open_writer,
    recording_files,
    records_poses_by_default,
    remove_recording,
    writes_scene,
)
from simreel.model.blocks import StepBlock

__all__ = [
    "open_writer",
    "check_writer_options",
    "open_reader",
    "format_of",
    "check_writable",
    "check_report_writable",
    "remove_recording",
    "recording_files",
    "records_poses_by_default",
    "writes_scene",
    "HDF5_SUFFIXES",
    "MCAP_SUFFIXES",
    "EpisodeReader",
    "EpisodeWriter",
    "EpisodeSink",
    "StepBlock",
]
