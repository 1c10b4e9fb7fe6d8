"""`Hdf5Writer`: streams episodes into an HDF5 recording (layout and format: `simreel.formats.hdf5.layout`),
safe against `kill -9`, full disks, signals and concurrent readers.

The writer keeps the file open for the whole recording but changes it only in commits. A running episode
stays in memory (up to 8 MiB) or streams into its own scratch file `<name>.h5.partial/traj_N.h5`, and a
line in the journal `running.jsonl` there names it when it begins. A commit writes the finished episode in one go and
ends with a flush, after which the file on disk is whole again; between commits nothing is written. So a
`kill -9` loses only the episodes still running (the journal names them). A commit

- first reserves the disk space it may need, so a full disk refuses it before the file is touched (the
  recording then stops with one line, every episode committed before readable);
- holds SIGINT/SIGTERM until it has ended (`simreel.io.durable`);
- holds the commit lock, so a reader in another process never reads the file half way through a commit
  (`simreel.io.lock`);
- then adds the episode to the JSON sidecar (`simreel.formats.maniskill.sidecar`).

A recording that replaces an existing one (`overwrite`) is written in the side folder and moved over the old
one by `close` (`simreel.io.staging`); a second writer of the same name is refused.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.errors import StorageError, UsageError
from simreel.formats.base import EpisodeSink, EpisodeWriter
from simreel.formats.hdf5.datasets import DatasetWriter, check_compression, image_storage
from simreel.formats.hdf5.layout import (
    EPISODE_ATTR,
    LIBVER,
    META_ATTR,
    VERSION_ATTR,
    encode_text,
    group_name,
    partial_dir,
    running_journal,
    scratch_path,
    sidecar_path,
)
from simreel.formats.maniskill.layout import OBS, dataset_name, refuse_replacing_sidecar
from simreel.formats.maniskill.sidecar import SidecarFile
from simreel.io.durable import (
    deferred_signals,
    is_storage_error,
    release_space,
    release_unused,
    reserve_space,
    storage_error,
)
from simreel.io.lock import CommitLock
from simreel.io.staging import RecordingTarget
from simreel.io.targets import check_name_lengths
from simreel.model.blocks import StepBlock
from simreel.model.meta import EpisodeMeta, RecordingMeta

__all__ = ["Hdf5Writer", "image_storage"]

_SPILL_BYTES = 8 << 20
"""A running episode is held in memory up to this size, then streamed to its scratch file."""
_RESERVE_SLACK = 64 << 10
_RESERVE_PER_DATASET = 4 << 10
"""Disk reserved per commit beyond the raw bytes of its arrays: object headers, group indexes, compression
that fails to shrink a chunk."""
_CACHE_BYTES = 64 << 10
_CACHE_PER_DATASET = 4 << 10
"""The writer's HDF5 metadata cache: this much plus this much per dataset of an episode (`_bound_metadata_cache`)."""


class _Hdf5Sink(EpisodeSink):
    """Holds an episode in memory up to `_SPILL_BYTES`, then streams it to a scratch file.

    A short episode never touches the disk (but for its line in the journal) until its commit writes it into the file in
    one go; a long one streams to `<name>.h5.partial/traj_N.h5` so memory stays bounded.
    """

    def __init__(self, writer: Hdf5Writer, meta: EpisodeMeta, reset: StepBlock) -> None:
        self._writer = writer
        self.index = meta.index
        self._scratch_path = scratch_path(writer.partial, meta.index)
        self._file: Any = None
        self._pending: dict[str, list[np.ndarray]] = {}
        self._pending_bytes = 0
        self._hold(writer.reset_arrays(meta, reset))
        writer.episode_began(meta)

    def _hold(self, arrays: dict[str, np.ndarray]) -> None:
        for name, rows in arrays.items():
            self._pending.setdefault(name, []).append(np.array(rows, copy=True))
            self._pending_bytes += rows.nbytes
        if self._pending_bytes > _SPILL_BYTES:
            self._writer.guard(self._spill, f"episode {self.index} was not committed")

    def _spill(self) -> None:
        import h5py

        if self._file is None:
            self._file = h5py.File(self._scratch_path, "w", locking=False)
        traj = self._file.require_group("traj")
        for name, parts in self._pending.items():
            rows = np.concatenate(parts)
            ds = traj.get(name)
            if ds is None:
                traj.create_dataset(name, data=rows, maxshape=(None, *rows.shape[1:]), chunks=True)
            else:
                n = ds.shape[0]
                ds.resize(n + rows.shape[0], axis=0)
                ds[n:] = rows
        self._pending.clear()
        self._pending_bytes = 0

    def append(self, block: StepBlock) -> None:
        self._writer._check_usable()
        self.check_running()
        self._hold(block.converted().conform(self._writer.fields, episode=self.index))
        self.steps += block.rows

    def commit(self, meta: EpisodeMeta) -> None:
        self._writer._check_usable()
        meta = self._writer.checked_meta(meta, EpisodeMeta)
        self.check_commit(meta)
        self.ended = True
        if self._file is None:
            arrays = {name: np.concatenate(parts) for name, parts in self._pending.items()}
            arrays.update({f.name: np.zeros((0, *f.shape), f.dtype) for f in self._writer.fields if f.name not in arrays})
            self._pending.clear()
            self._writer.commit_arrays(meta, arrays)
            return
        self._writer.guard(self._spill, f"episode {meta.index} was not committed")
        self._file.close()
        self._file = None
        self._writer.commit_scratch(meta, self._scratch_path)

    def discard(self) -> None:
        if self.ended:
            return
        self.ended = True
        self._pending.clear()
        if self._file is not None:
            self._file.close()
            self._file = None
        self._scratch_path.unlink(missing_ok=True)
        self._writer.episode_ended(self.index, committed=False)


class Hdf5Writer(EpisodeWriter):
    """Streams episodes into an HDF5 recording; see the module docstring and `simreel.formats.hdf5.layout`.

    Without `overwrite` it refuses a path whose file, JSON sidecar or `.partial/` folder exists (a user's
    own `NAME.json` is never replaced silently); with it, all three are replaced, the file only once the new
    recording is complete (`close`).

    Args:
        path: the .h5 file to write.
        meta: the recording's metadata; its field table decides the datasets of every episode.
        overwrite: replace an existing recording (and its side files) instead of refusing.
        compression: "gzip" (default), "lzf" or None; every dataset also gets the Fletcher-32 checksum.
    """

    def __init__(self, path: str | Path, meta: RecordingMeta, *, overwrite: bool = False,
                 compression: str | None = "gzip") -> None:
        super().__init__(path, meta)
        self._datasets = DatasetWriter(compression)
        self._writes_obs = any(dataset_name(f.name, meta).split("/")[0] == OBS for f in self.fields)
        """Whether an episode's datasets include `obs` (every commit writes every field, empty or not)."""
        self.compression = compression
        self.committed: list[EpisodeMeta] = []
        self._indices: set[int] = set()
        """Indices of the episodes begun so far (they must be unique)."""
        self._running: set[int] = set()
        self._journal_fd: int | None = None
        self._failed: StorageError | None = None
        self._closed = self._aborted = False
        refuse_replacing_sidecar(sidecar_path(self.path), writing=self.path, own=self.path)
        self._target = RecordingTarget.claim(self.path, self.side_paths(self.path), overwrite=overwrite)
        self.partial = self._target.folder
        try:
            self.partial.mkdir(exist_ok=True)
            self._commit_lock = CommitLock(self.partial)
            with self._commit_lock.held():
                self._file = _create_file(self._target.write_path, meta)
            _bound_metadata_cache(self._file, len(self.fields))
            self._sidecar = SidecarFile(self._target.beside(sidecar_path(self.path).name), meta)
        except OSError as e:
            self.abort()
            raise storage_error(self.path, e) if is_storage_error(e) else UsageError(
                f"cannot write {self.path}: {e.strerror or e}") from None
        except BaseException:
            self.abort()
            raise

    @classmethod
    def side_paths(cls, path: Path) -> list[Path]:
        return [sidecar_path(path), partial_dir(path)]

    @classmethod
    def check_options(cls, *, compression: str | None = "gzip") -> None:
        check_compression(compression)

    @classmethod
    def check_target(cls, path: Path, *, overwrite: bool) -> None:
        check_name_lengths(path, cls.side_paths(path))  # first: looking for the sidecar of a name too long fails
        refuse_replacing_sidecar(sidecar_path(path), writing=path, own=path)
        super().check_target(path, overwrite=overwrite)

    @property
    def _fd(self) -> int:
        """A descriptor of the file being written (the writer's lock on it)."""
        return self._target.locks[-1].fd

    # ---------------------------------------------------------------- episodes
    def begin_episode(self, meta: EpisodeMeta, reset: StepBlock) -> EpisodeSink:
        self._check_usable()
        meta = self.checked_meta(meta, EpisodeMeta)
        if meta.index in self._indices:
            raise UsageError(f"{self.path}: episode {meta.index} was already written; episode indices must be unique")
        return _Hdf5Sink(self, meta, reset)

    def episode_began(self, meta: EpisodeMeta) -> None:
        """Note in the journal that episode `meta.index` began, for whoever finds the folder after a crash."""
        line = {"began": meta.index, "env_idx": meta.env_idx, "seed": meta.seed}
        self.guard(lambda: self._journal(line), f"episode {meta.index} could not begin")
        self._indices.add(meta.index)
        self._running.add(meta.index)

    def episode_ended(self, index: int, *, committed: bool = True) -> None:
        """Episode `index` is no longer running: committed (the file says so) or discarded (the journal says so)."""
        self._running.discard(index)
        if not committed and self._journal_fd is not None and self._failed is None:
            with contextlib.suppress(OSError):  # unnoted, a crash before close would name it as running: no loss
                self._journal({"ended": index})

    def _journal(self, line: dict[str, Any]) -> None:
        """Append one line to the journal of running episodes (`running_journal`), opened at the first."""
        if self._journal_fd is None:
            self._journal_fd = os.open(running_journal(self.partial), os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        os.write(self._journal_fd, (json.dumps(line) + "\n").encode())

    def commit_arrays(self, meta: EpisodeMeta, arrays: dict[str, np.ndarray]) -> None:
        """Commit an episode held in memory: one dataset per field of `arrays`."""
        datasets, rec = self._datasets, self.meta

        def fill(group: Any) -> None:
            for name, a in arrays.items():
                datasets.write(group, dataset_name(name, rec), a)

        self._commit(meta, fill, sum(a.nbytes for a in arrays.values()))

    def commit_scratch(self, meta: EpisodeMeta, scratch: Path) -> None:
        """Commit a long episode from its scratch file, a few chunks at a time, then remove the scratch file."""
        import h5py

        with h5py.File(scratch, "r", locking=False) as src:
            traj = src["traj"]
            sources = {f.name: traj[f.name] for f in self.fields if f.name in traj}
            empty = {f.name: np.zeros((0, *f.shape), f.dtype) for f in self.fields if f.name not in traj}

            def fill(group: Any) -> None:
                for name, ds in sources.items():
                    self._datasets.copy(group, dataset_name(name, self.meta), ds)
                for name, a in empty.items():
                    self._datasets.write(group, dataset_name(name, self.meta), a)

            self._commit(meta, fill, sum(ds.size * ds.dtype.itemsize for ds in sources.values()))
        scratch.unlink()

    def _commit(self, meta: EpisodeMeta, fill: Callable[[Any], None], nbytes: int) -> None:
        """Write episode `meta.index` as group `traj_N` (`fill(group id)` writes its datasets), flush, add it to
        the sidecar. A failure leaves the file as it was after the previous commit and stops the writer."""
        self._check_usable()
        with deferred_signals():
            try:
                reserve_space(self._fd, nbytes + _RESERVE_SLACK + _RESERVE_PER_DATASET * len(self.fields))
                self._sidecar.reserve(meta)
            except OSError as e:
                raise self._fail(e, meta) from None
            try:
                with self._commit_lock.held():
                    group = self._datasets.group(self._file.id, group_name(meta.index))
                    fill(group)
                    if not self._writes_obs:  # ManiSkill's loader needs the group; its obs_mode="none" files
                        self._datasets.group(group, OBS)  # have it empty
                    self._datasets.text_attribute(group, EPISODE_ATTR, encode_text(json.dumps(meta.to_json())))
                    self._file.flush()
                    release_unused(self._fd, self._file.id.get_filesize())  # HDF5's end of allocated space
                self._sidecar.append(meta)
            except BaseException as e:
                raise self._fail(e, meta) from None
        self.committed.append(meta)
        self.episode_ended(meta.index)

    # ---------------------------------------------------------------- failures
    def _fail(self, e: BaseException, meta: EpisodeMeta | None = None, lost: str = "") -> BaseException:
        """Stop the writer after a failed write: nothing more reaches the file (a half-written commit must never
        be flushed), so it keeps exactly the episodes committed before. Returns the error to raise."""
        self._neutralize()
        if isinstance(e, OSError):
            return self._stop(e, f"episode {meta.index} was not committed" if meta is not None else lost)
        return e

    def _stop(self, e: OSError, lost: str = "") -> StorageError:
        self._neutralize()
        return super()._stop(e, lost)

    def _neutralize(self) -> None:
        """Point the HDF5 library's descriptor of the file at /dev/null, so whatever it still holds in memory of
        a commit that failed half way is never written (closing, or the end of the process, would flush it)."""
        file = getattr(self, "_file", None)
        if file is None or not file.id.valid:
            return
        try:
            fd = file.id.get_vfd_handle()
            null = os.open(os.devnull, os.O_RDWR)
            os.dup2(null, fd)
            os.close(null)
        except (OSError, ValueError, TypeError):
            pass
        try:
            file.close()
        except Exception:  # noqa: BLE001 - it writes nowhere now; a failure to close loses nothing
            pass
        self._file = None

    # ---------------------------------------------------------------- close
    def close(self, *, replace: bool = True) -> None:
        """Close the file, remove what the running episodes left in the side folder (they are not committed), and
        move a staged recording over the old one (unless not `replace`). After a failed write nothing replaces the
        old recording: the episodes committed before stay where they were written (the error said where)."""
        if self._closed:
            return
        self._closed = True
        try:
            with deferred_signals():
                if self._file is not None:
                    with self._commit_lock.held():
                        self._file.close()
                    self._file = None
                self._sidecar.close()
        except OSError as e:
            self._failed = self._failed or storage_error(self.path, e, committed=len(self.committed),
                                                         readable=self._where_readable)
            raise self._failed from None
        finally:
            with contextlib.suppress(OSError):
                release_space(self._fd)  # what the last commit reserved and did not use
            self._commit_lock.close()
            self._clear_running()
            if self._failed is None:
                self._target.publish([sidecar_path(self.path).name], replace=replace)
            else:
                self._target.release()

    @property
    def _where_readable(self) -> str:
        if self._target.staged:
            return f" in {self._target.write_path} (the recording it was to replace is unchanged)"
        return ""

    def abort(self) -> None:
        """Drop the recording: a new file is removed, a staged one too (the old recording stays)."""
        if self._aborted:
            return
        self._aborted = self._closed = True
        self._neutralize()
        for closing in (getattr(self, "_sidecar", None), getattr(self, "_commit_lock", None)):
            if closing is not None:
                closing.close()
        self._clear_running()
        self._target.abandon([sidecar_path(self.path).name])

    def _clear_running(self) -> None:
        """Remove what the running episodes left (they are not committed), the journal, and the side folder when
        nothing else is in it."""
        for index in list(self._running):
            scratch_path(self.partial, index).unlink(missing_ok=True)
        self._running.clear()
        if self._journal_fd is not None:
            os.close(self._journal_fd)
            self._journal_fd = None
        running_journal(self.partial).unlink(missing_ok=True)
        if not self._target.staged and self.partial.is_dir() and not any(self.partial.iterdir()):
            shutil.rmtree(self.partial, ignore_errors=True)


def _create_file(path: Path, meta: RecordingMeta) -> Any:
    """Create the recording (version-0 superblock, root group in the 1.10 format) and reopen it for the objects
    to come; returns the open `h5py.File`."""
    import h5py

    # earliest: the version-0 superblock, which has no "open for writing" flag; track_order: a root group in the
    # new format (checksummed, no local heap), also listing episodes in the order they were committed
    with h5py.File(path, "w", libver=("earliest", LIBVER[1]), track_order=True, locking=False):
        pass
    f = h5py.File(path, "r+", libver=LIBVER, locking=False)
    try:
        f.attrs[VERSION_ATTR] = FORMAT_VERSION
        f.attrs[META_ATTR] = encode_text(json.dumps(meta.to_json()))
        f.flush()
    except BaseException:
        f.close()
        raise
    return f


def _bound_metadata_cache(file: Any, datasets: int) -> None:
    """Fix the size of the HDF5 metadata cache of the writer's `file` (an open `h5py.File`) at a few commits' worth
    of metadata (`_CACHE_BYTES` + `_CACHE_PER_DATASET` per dataset of an episode).

    By default the cache grows to 2 MB (~9,600 entries of object headers and group indexes, all clean after each
    commit's flush) and every flush walks all of them, so a commit cost more the longer the recording ran: 5.6 ms
    per 50-step PickCube episode at episode 50, 7.7 ms at 2,000. Bounded, it stays at 5.6-5.9 ms
    (`benchmarks/bench_commit.py`). The bound keeps a whole commit's new metadata in the cache, so a commit still
    changes none of the file's earlier bytes before its flush (a smaller cache, 16 KB for PickCube's 16 datasets,
    evicts dirty entries of the root group mid-commit). It is this handle's setting only: nothing of it is stored in
    the file, and readers keep their own cache.
    """
    config = file.id.get_mdc_config()
    config.set_initial_size = True
    config.initial_size = config.max_size = _CACHE_BYTES + _CACHE_PER_DATASET * datasets
    config.min_size = config.max_size // 2
    config.incr_mode = config.decr_mode = config.flash_incr_mode = 0  # H5C_incr__off, H5C_decr__off, H5C_flash_incr__off
    file.id.set_mdc_config(config)
