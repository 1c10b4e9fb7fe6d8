"""HDF5 recordings: ManiSkill's `traj_N` layout plus simreel's metadata (`layout`), written kill-safe
(`writer`), read episode by episode (`reader`), with ManiSkill's JSON sidecar beside them
(`simreel.formats.maniskill.sidecar`)."""

from simreel.formats.hdf5.layout import HDF5_MAGIC, partial_dir, sidecar_path
from simreel.formats.hdf5.reader import Hdf5Reader
from simreel.formats.hdf5.writer import Hdf5Writer

__all__ = ["Hdf5Reader", "Hdf5Writer", "HDF5_MAGIC", "partial_dir", "sidecar_path"]
