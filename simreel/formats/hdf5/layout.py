"""What simreel's HDF5 writer and reader share: the file layout, its names and its magic bytes.

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
    <name>.h5.partial/      episodes still being recorded (scratch files, removed when committed)

Datasets inside `traj_N` are the recording's fields (`simreel.episode.episode_fields`) under their flat names,
laid out as ManiSkill lays them out (`simreel.formats.maniskill.layout`: a bare-array observation is the dataset
`obs`), so ManiSkill's own tools read the file.
"""

from __future__ import annotations

from pathlib import Path

from simreel.formats.maniskill.layout import group_name, sidecar_path

__all__ = ["HDF5_MAGIC", "META_ATTR", "VERSION_ATTR", "EPISODE_ATTR", "group_name", "sidecar_path", "partial_dir"]

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
META_ATTR = "simreel_meta"
VERSION_ATTR = "simreel_format_version"
EPISODE_ATTR = "simreel_episode"


def partial_dir(path: Path) -> Path:
    """Where running episodes stream before they are committed."""
    return path.with_name(path.name + ".partial")
