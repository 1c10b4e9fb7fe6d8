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
episode stays in memory (up to 8 MiB) or streams into its own scratch file under `<name>.h5.partial/`,
and the main file is opened only for the few milliseconds in which a finished episode is written in
(then closed). A killed recording therefore leaves every committed episode readable and loses only the
episodes still running. The JSON sidecar, which only ManiSkill's tools need, is rewritten at most once
a second while recording and at close.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.episode import FLAG_FIELDS, Episode, EpisodeMeta, RecordingMeta, json_default
from simreel.errors import RecordingFileError, UsageError
from simreel.formats.base import EpisodeReader, EpisodeSink, EpisodeWriter, StepBlock, reset_row

__all__ = ["Hdf5Writer", "Hdf5Reader", "HDF5_MAGIC", "sidecar_path", "partial_dir"]

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_CHUNK_BYTES = 1 << 20
_CONTIGUOUS_MAX_BYTES = 256 << 10
_SPILL_BYTES = 8 << 20
"""A running episode is held in memory up to this size, then streamed to its scratch file."""
_SIDECAR_PERIOD_S = 1.0
"""The JSON sidecar is rewritten at most this often while recording (and always at close)."""
_LOCK_WAIT_S = 30.0


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


def _write_final(group: Any, name: str, data: Any, compression: str | None) -> None:
    """Write a finished dataset laid out for its size: contiguous when small, chunked + compressed when large.

    Contiguous datasets need no chunk index, which would otherwise be most of a short episode's bytes.
    `data` is an array or an h5py dataset (copied in slices, so a large one never sits in memory whole).
    """
    nbytes = data.size * data.dtype.itemsize
    if nbytes <= _CONTIGUOUS_MAX_BYTES or data.shape[0] == 0:
        group.create_dataset(name, data=data[()])
        return
    shape = data.shape[1:]
    rows = _chunk_rows(shape, data.dtype.itemsize)
    out = group.create_dataset(name, shape=data.shape, dtype=data.dtype, chunks=(rows, *shape),
                               compression=compression)
    step = rows * 16
    for start in range(0, data.shape[0], step):
        out[start : start + step] = data[start : start + step]


def _empty_step_fields(meta: RecordingMeta) -> dict[str, np.ndarray]:
    """Every per-step dataset with zero rows: a zero-step episode still has them all."""
    out = {
        "actions": np.zeros((0, *meta.action_space.get("shape", [0])), np.float32),
        "rewards": np.zeros(0, np.float32),
        **{name: np.zeros(0, bool) for name in FLAG_FIELDS},
        **{f"info/{k}": np.zeros((0, *spec.shape), spec.dtype) for k, spec in meta.info_layout.items()},
    }
    if meta.contact_channels:
        out["contact_forces"] = np.zeros((0, len(meta.contact_channels), 3), np.float32)
    return out


def _block_fields(block: StepBlock) -> dict[str, np.ndarray]:
    """A block's arrays keyed by their dataset path inside `traj_N`, in their stored dtypes."""
    out = {
        "actions": np.asarray(block.actions, dtype=np.float32),
        "rewards": np.asarray(block.rewards, dtype=np.float32),
        **{name: np.asarray(getattr(block, name), dtype=bool) for name in FLAG_FIELDS},
    }
    for group in ("env_states", "obs", "info"):
        for p, a in getattr(block, group).items():
            out[f"{group}/{p}"] = a
    if block.contact_forces is not None:
        out["contact_forces"] = np.asarray(block.contact_forces, dtype=np.float32)
    if block.body_poses is not None:
        out["body_poses"] = np.asarray(block.body_poses, dtype=np.float32)
    return out


class _Hdf5Sink(EpisodeSink):
    """Holds an episode in memory up to `_SPILL_BYTES`, then streams it to a scratch file.

    A short episode never touches the disk until its commit writes it into the main file in one go;
    a long one streams to `<name>.h5.partial/traj_N.h5` so memory stays bounded.
    """

    def __init__(
        self,
        writer: Hdf5Writer,
        meta: EpisodeMeta,
        initial_state: dict[str, np.ndarray],
        initial_obs: dict[str, np.ndarray] | None,
        initial_poses: np.ndarray | None,
    ) -> None:
        self._writer = writer
        self._meta = meta
        self._scratch_path = writer._partial / f"traj_{meta.index}.h5"
        self._file: Any = None
        self._pending: dict[str, list[np.ndarray]] = {}
        self._pending_bytes = 0
        self._hold(reset_row(initial_state, initial_obs, initial_poses))

    def _hold(self, fields: dict[str, np.ndarray]) -> None:
        for name, rows in fields.items():
            self._pending.setdefault(name, []).append(np.array(rows, copy=True))
            self._pending_bytes += rows.nbytes
        if self._pending_bytes > _SPILL_BYTES:
            self._spill()

    def _spill(self) -> None:
        import h5py

        if self._file is None:
            self._file = h5py.File(self._scratch_path, "w")
        traj = self._file.require_group("traj")
        for name, parts in self._pending.items():
            _append(traj, name, np.concatenate(parts), self._writer.compression)
        self._pending.clear()
        self._pending_bytes = 0

    def append(self, block: StepBlock) -> None:
        self._hold(_block_fields(block))

    def commit(self, meta: EpisodeMeta) -> None:
        if self._file is None:
            fields = {name: np.concatenate(parts) for name, parts in self._pending.items()}
            for name, empty in _empty_step_fields(self._writer.meta).items():
                fields.setdefault(name, empty)
            self._writer._commit(meta, lambda group: [
                _write_final(group, name, a, self._writer.compression) for name, a in fields.items()
            ])
            return
        self._spill()
        traj = self._file["traj"]
        for name, empty in _empty_step_fields(self._writer.meta).items():
            if name not in traj:
                traj.create_dataset(name, data=empty)
        self._file.close()
        import h5py

        with h5py.File(self._scratch_path, "r") as src:
            def copy(group: Any) -> None:
                src["traj"].visititems(
                    lambda name, obj: _write_final(group, name, obj, self._writer.compression)
                    if isinstance(obj, h5py.Dataset) else None
                )

            self._writer._commit(meta, copy)
        self._scratch_path.unlink()

    def discard(self) -> None:
        self._pending.clear()
        if self._file is not None:
            self._file.close()
            self._scratch_path.unlink(missing_ok=True)


class Hdf5Writer(EpisodeWriter):
    """Streams episodes into an HDF5 recording; see the module docstring for the layout.

    Without `overwrite` it refuses a path whose file, JSON sidecar or `.partial/` folder exists (a user's
    own `NAME.json` is never replaced silently); with it, all three are replaced.
    """

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
        self._sidecar_written = 0.0
        self.check_target(self.path, overwrite=overwrite)
        self.remove(self.path)  # with overwrite: the old recording; without, check_target saw none of it
        try:
            f = h5py.File(self.path, "x")  # "x": never replaces a file created since the check
        except FileExistsError:
            raise UsageError(f"{self.path} already exists; pass --overwrite to replace it") from None
        except OSError as e:
            raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
        try:
            with f:
                f.attrs["simreel_format_version"] = FORMAT_VERSION
                f.attrs["simreel_meta"] = json.dumps(meta.to_json())
            self._partial.mkdir()
            self._write_sidecar()
        except OSError as e:
            self.remove(self.path)  # all of it was created above
            raise UsageError(f"cannot write {self.path}: {e.strerror or e}") from None
        except BaseException:
            self.remove(self.path)
            raise

    @classmethod
    def side_paths(cls, path: Path) -> list[Path]:
        return [sidecar_path(path), partial_dir(path)]

    def begin_episode(
        self,
        meta: EpisodeMeta,
        initial_state: dict[str, np.ndarray],
        initial_obs: dict[str, np.ndarray] | None = None,
        initial_poses: np.ndarray | None = None,
    ) -> EpisodeSink:
        return _Hdf5Sink(self, meta, initial_state, initial_obs, initial_poses)

    def _commit(self, meta: EpisodeMeta, fill: Any) -> None:
        """Create `traj_<index>` in the main file, let `fill(group)` write its datasets, close the file."""
        with self._open_main() as dst:
            group = dst.create_group(f"traj_{meta.index}")
            fill(group)
            group.attrs["simreel_episode"] = json.dumps(meta.to_json())
        self._committed.append(meta)
        if time.monotonic() - self._sidecar_written >= _SIDECAR_PERIOD_S:
            self._write_sidecar()

    def _open_main(self) -> Any:
        """The main file for appending; waits while a reader that locks files (HDF5's default) has it open."""
        import h5py

        deadline = time.monotonic() + _LOCK_WAIT_S
        while True:
            try:
                return h5py.File(self.path, "a")
            except (BlockingIOError, OSError) as e:
                if "lock" not in str(e).lower() or time.monotonic() > deadline:
                    raise
                time.sleep(0.05)

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
        self._sidecar_written = time.monotonic()

    def close(self) -> None:
        self._write_sidecar()
        if self._partial.is_dir() and not any(self._partial.iterdir()):
            self._partial.rmdir()


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
            # No file lock: a reader must never make a running recorder fail to commit.
            self._file = h5py.File(self.path, "r", locking=False)
        except OSError as e:
            raise RecordingFileError(self.path, _open_problem(e)) from None
        attrs = self._file.attrs
        if "simreel_meta" not in attrs:
            self._file.close()
            raise RecordingFileError(
                self.path, "an HDF5 file without simreel metadata (not a simreel recording)"
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
