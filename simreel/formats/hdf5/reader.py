"""`Hdf5Reader`: reads a simreel HDF5 recording (layout: `simreel.formats.hdf5.layout`), episode by episode."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from simreel import FORMAT_VERSION
from simreel.episode import Episode, EpisodeMeta, RecordingMeta, episode_fields
from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeReader
from simreel.formats.hdf5.layout import (
    EPISODE_ATTR,
    HDF5_MAGIC,
    META_ATTR,
    VERSION_ATTR,
    group_name,
    partial_dir,
)
from simreel.formats.maniskill.layout import dataset_name

__all__ = ["Hdf5Reader", "open_hdf5", "holds_simreel_metadata"]


def open_hdf5(path: Path) -> Any:
    """`path` as a read-only `h5py.File`, without a file lock (a reader must never make a running recorder fail
    to commit); `RecordingFileError` saying what a failure to open means."""
    import h5py

    try:
        return h5py.File(path, "r", locking=False)
    except OSError as e:
        raise RecordingFileError(path, _open_problem(e)) from None


def holds_simreel_metadata(path: Path) -> bool:
    """Whether the HDF5 file `path` carries simreel's metadata (True also when it cannot be opened: the simreel
    reader then says why)."""
    try:
        with open_hdf5(path) as f:
            return META_ATTR in f.attrs
    except RecordingFileError:
        return True


def _open_problem(e: OSError) -> str:
    """What h5py's failure to open a file with a valid signature means, for a `RecordingFileError`."""
    text = str(e)
    if "locking flag" in text:
        # HDF5 opens a file once per process: an h5py.File of it still open elsewhere in this process, made
        # with file locking on (h5py's default), cannot share its handle with this lock-free reader.
        return (
            "already open in this process through h5py with file locking on (h5py: file locking flag values "
            "don't match); close that h5py.File, or open it with locking=False, then read it again"
        )
    if "already open" in text:
        return (
            f"marked as open by another HDF5 writer (h5py: {text}); read it once that writer has closed it, "
            "or, if it died, clear the mark with `h5clear -s FILE`"
        )
    return f"truncated or corrupt HDF5 file ({text})"


class Hdf5Reader(EpisodeReader):
    """Reads a simreel HDF5 recording. Raises `RecordingFileError` for anything else."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingFileError(self.path, "no such file")
        with open(self.path, "rb") as fh:
            if fh.read(len(HDF5_MAGIC)) != HDF5_MAGIC:
                raise RecordingFileError(self.path, "not an HDF5 file")
        self._file = open_hdf5(self.path)
        try:
            self.meta = self._read_meta()
        except BaseException:
            self._file.close()
            raise
        self.fields = episode_fields(self.meta)
        self.kind = f"simreel HDF5 recording (format {self.meta.format_version})"
        self.episodes = self._read_episode_metas()
        scratch = partial_dir(self.path)
        self.unfinished = sorted(p.name for p in scratch.glob("traj_*.h5")) if scratch.is_dir() else []
        """Scratch files of episodes that were running when a recording process died."""

    def _read_meta(self) -> RecordingMeta:
        attrs = self._file.attrs
        if META_ATTR not in attrs:
            raise RecordingFileError(self.path, "an HDF5 file without simreel metadata (not a simreel recording)")
        version = int(attrs.get(VERSION_ATTR, 0))
        if version > FORMAT_VERSION:
            raise RecordingFileError(
                self.path,
                f"format version {version} is newer than this simreel reads ({FORMAT_VERSION}); upgrade simreel",
            )
        try:
            return RecordingMeta.from_json(json.loads(attrs[META_ATTR]))
        except (ValueError, TypeError) as e:  # MetadataError and JSONDecodeError are ValueErrors
            raise RecordingFileError(self.path, f"bad simreel metadata ({e})") from None

    def _read_episode_metas(self) -> list[EpisodeMeta]:
        metas = []
        for name in self._file:
            if not (name.startswith("traj_") and EPISODE_ATTR in self._file[name].attrs):
                continue
            try:
                metas.append(EpisodeMeta.from_json(json.loads(self._file[name].attrs[EPISODE_ATTR])))
            except (ValueError, TypeError) as e:
                raise RecordingFileError(self.path, f"{name}: bad episode metadata ({e})") from None
        return sorted(metas, key=lambda m: m.index)

    def read_episode(self, index: int) -> Episode:
        meta = self.episode_meta(index)
        group = self._file[group_name(index)]
        names = {f.name: self._dataset(group, f.name) for f in self.fields}
        missing = [d for d in names.values() if d not in group]
        if missing:
            raise RecordingFileError(self.path, f"{group_name(index)} lacks a dataset: {missing[0]!r}")
        return Episode.from_fields(meta, {f: group[d][()] for f, d in names.items()})

    def _dataset(self, group: Any, field: str) -> str:
        """Where `field` is in `group`: ManiSkill's layout, or simreel's format-1 name (a bare-array observation
        as ``obs/<obs mode>``)."""
        name = dataset_name(field, self.meta)
        return name if name in group or field not in group else field

    def close(self) -> None:
        self._file.close()
