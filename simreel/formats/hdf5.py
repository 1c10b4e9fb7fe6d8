"""HDF5 recordings: ManiSkill's `traj_N` layout plus simreel's metadata, safe against `kill -9`.

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

Crash safety: h5py leaves a file that is being written unreadable when the process dies. So a running
episode streams into its own scratch file under `<name>.h5.partial/`, and the main file is opened only
for the few milliseconds in which a finished episode is copied in (then closed). A killed recording
therefore leaves every committed episode readable and loses only the episodes still running.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.episode import Episode, EpisodeMeta, RecordingMeta, json_default
from simreel.errors import RecordingFileError, UsageError
from simreel.formats.base import EpisodeReader, EpisodeSink, EpisodeWriter, StepBlock

__all__ = ["Hdf5Writer", "Hdf5Reader", "HDF5_MAGIC", "sidecar_path", "partial_dir"]

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_CHUNK_BYTES = 1 << 20


def sidecar_path(path: Path) -> Path:
    """ManiSkill's JSON sidecar beside `path` (`x.h5` → `x.json`)."""
    return path.with_suffix(".json")


def partial_dir(path: Path) -> Path:
    """Where running episodes stream before they are committed."""
    return path.with_name(path.name + ".partial")


def _chunk_rows(row_shape: tuple[int, ...], itemsize: int) -> int:
    row_bytes = max(1, int(np.prod(row_shape, dtype=np.int64)) * itemsize)
    return int(max(1, min(256, _CHUNK_BYTES // row_bytes)))


def _append(group: Any, name: str, rows: np.ndarray, compression: str | None) -> None:
    """Append rows to dataset `name` of `group`, creating it resizable on first use."""
    ds = group.get(name)
    if ds is None:
        shape = rows.shape[1:]
        group.create_dataset(
            name,
            data=rows,
            maxshape=(None, *shape),
            chunks=(_chunk_rows(shape, rows.dtype.itemsize), *shape),
            compression=compression,
        )
        return
    n = ds.shape[0]
    ds.resize(n + rows.shape[0], axis=0)
    ds[n:] = rows


class _Hdf5Sink(EpisodeSink):
    def __init__(
        self,
        writer: Hdf5Writer,
        meta: EpisodeMeta,
        initial_state: dict[str, np.ndarray],
        initial_obs: dict[str, np.ndarray] | None,
        initial_poses: np.ndarray | None,
    ) -> None:
        import h5py

        self._writer = writer
        self._scratch_path = writer._partial / f"traj_{meta.index}.h5"
        self._file = h5py.File(self._scratch_path, "w")
        self._traj = self._file.create_group("traj")
        self._traj.attrs["simreel_episode"] = json.dumps(meta.to_json())
        c = writer.compression
        for p, a in initial_state.items():
            _append(self._traj, f"env_states/{p}", np.asarray(a)[None], c)
        for p, a in (initial_obs or {}).items():
            _append(self._traj, f"obs/{p}", np.asarray(a)[None], c)
        if initial_poses is not None:
            _append(self._traj, "body_poses", np.asarray(initial_poses, dtype=np.float32)[None], c)

    def append(self, block: StepBlock) -> None:
        c, t = self._writer.compression, self._traj
        _append(t, "actions", np.asarray(block.actions, dtype=np.float32), c)
        _append(t, "rewards", np.asarray(block.rewards, dtype=np.float32), c)
        for name in ("terminated", "truncated", "success", "fail"):
            _append(t, name, np.asarray(getattr(block, name), dtype=bool), c)
        for group in ("env_states", "obs", "info"):
            for p, a in getattr(block, group).items():
                _append(t, f"{group}/{p}", a, c)
        if block.contact_forces is not None:
            _append(t, "contact_forces", np.asarray(block.contact_forces, dtype=np.float32), c)
        if block.body_poses is not None:
            _append(t, "body_poses", np.asarray(block.body_poses, dtype=np.float32), c)

    def _ensure_step_datasets(self) -> None:
        """A zero-step episode still gets every per-step dataset, empty, with the right row shape."""
        t, meta = self._traj, self._writer.meta
        if "actions" in t:
            return
        t.create_dataset("actions", shape=(0, *meta.action_space.get("shape", [0])), dtype=np.float32)
        t.create_dataset("rewards", shape=(0,), dtype=np.float32)
        for name in ("terminated", "truncated", "success", "fail"):
            t.create_dataset(name, shape=(0,), dtype=bool)
        if meta.contact_channels:
            t.create_dataset("contact_forces", shape=(0, len(meta.contact_channels), 3), dtype=np.float32)

    def commit(self, meta: EpisodeMeta) -> None:
        self._ensure_step_datasets()
        self._traj.attrs["simreel_episode"] = json.dumps(meta.to_json())
        self._file.close()
        self._writer._commit_scratch(self._scratch_path, meta)

    def discard(self) -> None:
        self._file.close()
        self._scratch_path.unlink(missing_ok=True)


class Hdf5Writer(EpisodeWriter):
    """Streams episodes into an HDF5 recording; see the module docstring for the layout."""

    def __init__(
        self,
        path: str | Path,
        meta: RecordingMeta,
        *,
        overwrite: bool = False,
        compression: str | None = "lzf",
    ) -> None:
        import h5py

        super().__init__(path, meta)
        self.compression = compression
        self._partial = partial_dir(self.path)
        self._committed: list[EpisodeMeta] = []
        if not self.path.parent.is_dir():
            raise UsageError(f"cannot write {self.path}: folder {self.path.parent} does not exist")
        if self.path.exists() and not overwrite:
            raise UsageError(f"{self.path} already exists; pass --overwrite to replace it")
        for stale in (self.path, sidecar_path(self.path)):
            stale.unlink(missing_ok=True)
        shutil.rmtree(self._partial, ignore_errors=True)
        try:
            with h5py.File(self.path, "w") as f:
                f.attrs["simreel_format_version"] = FORMAT_VERSION
                f.attrs["simreel_meta"] = json.dumps(meta.to_json())
            self._partial.mkdir()
        except OSError as e:
            raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
        self._write_sidecar()

    def begin_episode(
        self,
        meta: EpisodeMeta,
        initial_state: dict[str, np.ndarray],
        initial_obs: dict[str, np.ndarray] | None = None,
        initial_poses: np.ndarray | None = None,
    ) -> EpisodeSink:
        return _Hdf5Sink(self, meta, initial_state, initial_obs, initial_poses)

    def _commit_scratch(self, scratch_path: Path, meta: EpisodeMeta) -> None:
        import h5py

        with h5py.File(scratch_path, "r") as src, h5py.File(self.path, "a") as dst:
            src.copy(src["traj"], dst, name=f"traj_{meta.index}")
        scratch_path.unlink()
        self._committed.append(meta)
        self._write_sidecar()

    def _write_sidecar(self) -> None:
        m = self.meta
        env_kwargs = {
            **m.env_kwargs,
            "obs_mode": m.obs_mode,
            "control_mode": m.control_mode,
            "sim_backend": m.sim_backend,
            "render_backend": m.render_backend,
            "reward_mode": m.reward_mode,
        }
        doc = {
            "env_info": {
                "env_id": m.env_id,
                "env_kwargs": {k: v for k, v in env_kwargs.items() if v is not None},
                "max_episode_steps": m.max_episode_steps,
            },
            "source_type": "simreel",
            "source_desc": m.command,
            "episodes": [
                {
                    "episode_id": e.index,
                    "episode_seed": e.seed,
                    "reset_kwargs": {"seed": e.seed, **({"options": e.reset_options} if e.reset_options else {})},
                    "control_mode": m.control_mode,
                    "elapsed_steps": e.length,
                    "success": e.success,
                }
                for e in self._committed
            ],
        }
        side = sidecar_path(self.path)
        tmp = side.with_name(side.name + ".tmp")
        tmp.write_text(json.dumps(doc, indent=2, default=json_default))
        os.replace(tmp, side)

    def close(self) -> None:
        if self._partial.is_dir() and not any(self._partial.iterdir()):
            self._partial.rmdir()


def _read_group(group: Any) -> dict[str, np.ndarray]:
    """Every dataset below `group`, keyed by its path relative to the group."""
    import h5py

    out: dict[str, np.ndarray] = {}

    def visit(name: str, obj: Any) -> None:
        if isinstance(obj, h5py.Dataset):
            out[name] = obj[()]

    group.visititems(visit)
    return out


class Hdf5Reader(EpisodeReader):
    """Reads a simreel HDF5 recording. Raises `RecordingFileError` for anything else."""

    def __init__(self, path: str | Path) -> None:
        import h5py

        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingFileError(self.path, "no such file")
        with open(self.path, "rb") as fh:
            if fh.read(8) != HDF5_MAGIC:
                raise RecordingFileError(self.path, "not an HDF5 file")
        try:
            self._file = h5py.File(self.path, "r")
        except OSError as e:
            raise RecordingFileError(self.path, f"truncated or corrupt HDF5 file ({e})") from None
        attrs = self._file.attrs
        if "simreel_meta" not in attrs:
            self._file.close()
            raise RecordingFileError(
                self.path, "an HDF5 file without simreel metadata (not recorded by simreel)"
            )
        version = int(attrs.get("simreel_format_version", 0))
        if version > FORMAT_VERSION:
            self._file.close()
            raise RecordingFileError(
                self.path,
                f"format version {version} is newer than this simreel reads ({FORMAT_VERSION}); upgrade simreel",
            )
        self.meta = RecordingMeta.from_json(json.loads(attrs["simreel_meta"]))
        self.episodes = []
        for name in self._file:
            if name.startswith("traj_") and "simreel_episode" in self._file[name].attrs:
                self.episodes.append(EpisodeMeta.from_json(json.loads(self._file[name].attrs["simreel_episode"])))
        self.episodes.sort(key=lambda m: m.index)
        scratch = partial_dir(self.path)
        self.unfinished = sorted(p.name for p in scratch.glob("traj_*.h5")) if scratch.is_dir() else []
        """Scratch files of episodes that were running when a recording process died."""

    def read_episode(self, index: int) -> Episode:
        meta = self.episode_meta(index)
        g = self._file[f"traj_{index}"]
        try:
            return Episode(
                meta=meta,
                actions=g["actions"][()],
                rewards=g["rewards"][()],
                terminated=g["terminated"][()],
                truncated=g["truncated"][()],
                success=g["success"][()],
                fail=g["fail"][()],
                env_states=_read_group(g["env_states"]),
                obs=_read_group(g["obs"]) if "obs" in g else {},
                info=_read_group(g["info"]) if "info" in g else {},
                contact_forces=g["contact_forces"][()] if "contact_forces" in g else None,
                body_poses=g["body_poses"][()] if "body_poses" in g else None,
            )
        except KeyError as e:
            raise RecordingFileError(self.path, f"traj_{index} lacks a dataset: {e}") from None

    def close(self) -> None:
        self._file.close()
