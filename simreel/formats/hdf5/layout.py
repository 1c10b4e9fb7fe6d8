"""What simreel's HDF5 writer and reader share: the file layout, its names, its magic bytes and its format.

Layout (ManiSkill-compatible where ManiSkill has a convention)::

    /                       attrs: simreel_format_version, simreel_meta (RecordingMeta JSON)
    /traj_N/                attrs: simreel_episode (EpisodeMeta JSON)
        actions rewards terminated truncated success fail        (T, ...)
        env_states/<key path>                                    (T+1, ...)
        obs/<key path>                                           (T+1, ...)  when recorded
        info/<key>                                               (T, ...)
        contact_forces                                           (T, C, 3)   C = len(meta.contact_channels)
        body_poses                                               (T+1, B, 7) B = len(meta.pose_bodies), optional
    <name>.json             ManiSkill's sidecar (env_info, episodes[]) for its own tools
    <name>.h5.partial/      while recording: running.jsonl (the episodes begun, `running_journal`), traj_N.h5
                            (a long running episode's scratch file); <name>.h5 and <name>.json of a recording that
                            replaces an existing one (`simreel.io.staging`)

Datasets inside `traj_N` are the recording's fields (`simreel.model.fields.episode_fields`) under their flat names,
laid out as ManiSkill lays them out (`simreel.formats.maniskill.layout`: a bare-array observation is the dataset
`obs`), so ManiSkill's own tools read the file.

How the bytes are stored (every h5py reads it without plugins, HDF5 >= 1.10): objects in the HDF5 1.10 format,
whose metadata (object headers, group indexes, chunk indexes) carries checksums, with a version-0 superblock,
which has no "open for writing" flag that a killed writer could leave set; every dataset chunked, each chunk
through shuffle + gzip and the Fletcher-32 checksum, so corrupted data fails to read instead of being read;
attributes as fixed-length ASCII strings, stored in their (checksummed) object header. Files written by
earlier simreel versions (no checksums, attributes in a global heap) are still read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from simreel.formats.maniskill.layout import group_name, sidecar_path
from simreel.io.staging import side_folder

__all__ = [
    "HDF5_MAGIC",
    "META_ATTR",
    "VERSION_ATTR",
    "EPISODE_ATTR",
    "LIBVER",
    "group_name",
    "sidecar_path",
    "partial_dir",
    "running_journal",
    "scratch_path",
    "encode_text",
    "decode_text",
]

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
META_ATTR = "simreel_meta"
VERSION_ATTR = "simreel_format_version"
EPISODE_ATTR = "simreel_episode"
LIBVER = ("v110", "v110")
"""HDF5 format bounds objects are written with: the 1.10 format (checksummed metadata), readable by HDF5 >= 1.10."""

partial_dir = side_folder
"""Where the writer keeps its journal of running episodes and their scratch files (`x.h5` → `x.h5.partial`)."""


def running_journal(folder: Path) -> Path:
    """The writer's journal of episodes: a JSON line ``{"began": N, "env_idx": ..., "seed": ...}`` when episode N
    begins, ``{"ended": N}`` when it is discarded. The episodes it says began, neither ended nor in the file, were
    running when the writer stopped. One appended line costs a fifth of a marker file created and removed per
    episode. Removed when the writer closes."""
    return folder / "running.jsonl"


def scratch_path(folder: Path, index: int) -> Path:
    """Where a long running episode streams before it is committed."""
    return folder / f"{group_name(index)}.h5"


def encode_text(text: str) -> np.bytes_:
    """A string attribute stored in the object header (fixed-length ASCII), not in a global heap."""
    return np.bytes_(text.encode("ascii", "backslashreplace"))


def decode_text(value: Any) -> str:
    """An attribute written by `encode_text` or, by earlier versions, as a variable-length string."""
    if isinstance(value, bytes | np.bytes_):
        return bytes(value).decode("ascii", "replace")
    return str(value)
