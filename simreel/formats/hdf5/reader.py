"""`Hdf5Reader`: reads a simreel HDF5 recording (layout: `simreel.formats.hdf5.layout`), episode by episode, checking
every episode against the recording's own layout, and naming what it cannot read rather than skipping it.

- A file still being written is read under the writer's commit lock (`simreel.io.lock`): the reader sees
  the episodes committed when it opened it, never a commit half done, and keeps a handle of each episode's
  group so it never walks the parts of the file a later commit changes.
- An episode whose group or metadata is corrupt or half written (a crash in a commit, a damaged disk) is listed
  in `damaged` with what is wrong; the others stay readable. An episode's data that fails its checksum, or
  that does not fit the layout (a field missing, another dtype or shape, a dataset the layout does not list)
  raises `RecordingFileError` naming the episode and the field: the layout when the episode is opened
  (`open_episode`), the checksum of each chunk when a block of rows that it holds is read (`Hdf5Rows`).
- Files of earlier simreel versions keep their attributes in HDF5 global heaps, where some corruptions make
  libhdf5 loop forever; those heaps are checked before libhdf5 reads them (`_check_global_heaps`).
- The JSON sidecar beside the file (for ManiSkill's tools, which read it instead of the .h5's metadata) is compared
  with the sidecar simreel writes for what the .h5 holds (`_sidecar_disagreement`): one that lists fewer or more
  episodes, or other seeds, reset options, lengths, env id, obs or control mode, is named in `notes` (`inspect`,
  `recover`, which rewrites it); simreel itself reads the .h5 alone.
"""

from __future__ import annotations

import json
import mmap
import struct
from collections.abc import Collection, Iterable, Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeReader, EpisodeRows, closed_reader, not_a_file
from simreel.formats.hdf5.layout import (
    EPISODE_ATTR,
    HDF5_MAGIC,
    META_ATTR,
    VERSION_ATTR,
    decode_text,
    group_name,
    partial_dir,
    running_journal,
    scratch_path,
)
from simreel.formats.maniskill.layout import dataset_name, group_index, sidecar_path
from simreel.formats.maniskill.sidecar import sidecar_document
from simreel.io.durable import errno_of
from simreel.io.lock import CommitLock, being_written
from simreel.io.paths import read_head, read_problem
from simreel.io.staging import replacement_note
from simreel.model.blocks import StepBlock
from simreel.model.fields import FieldSpec, episode_fields
from simreel.model.json_input import json_value
from simreel.model.meta import EpisodeMeta, RecordingMeta, json_default

__all__ = ["Hdf5Reader", "Hdf5Rows", "open_hdf5", "holds_simreel_metadata", "unlisted_datasets_problem", "datasets_below",
           "H5PY_ERRORS"]


H5PY_ERRORS = (OSError, KeyError, ValueError, TypeError, RuntimeError, AttributeError, IndexError)
"""What h5py raises for a corrupt file (libhdf5's errors surface as any of these)."""


def open_hdf5(path: Path) -> Any:
    """`path` as a read-only `h5py.File`, without a file lock (a reader must never make a running recorder fail
    to commit); `RecordingFileError` saying what a failure to open means."""
    import h5py

    try:
        return h5py.File(path, "r", locking=False)
    except OSError as e:
        raise RecordingFileError(path, read_problem(errno_of(e)) or _open_problem(e)) from None
    except H5PY_ERRORS as e:
        raise RecordingFileError(path, f"corrupt HDF5 file ({type(e).__name__}: {e})") from None


def holds_simreel_metadata(path: Path) -> bool:
    """Whether the HDF5 file `path` carries simreel's metadata (True also when it cannot be read: the simreel
    reader then says why). A file being recorded is read under its writer's commit lock, as `Hdf5Reader` reads it."""
    try:
        with CommitLock.reading(partial_dir(path), path) if being_written(path) else nullcontext(), \
                open_hdf5(path) as f:
            return META_ATTR in f.attrs
    except (RecordingFileError, *H5PY_ERRORS):
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


def _check_global_heaps(path: Path) -> None:
    """Refuse a file with a global heap collection that would make libhdf5 loop forever (an object of size 0
    where it expects the heap's free space; seen after 64 zeroed bytes). Walks each collection's objects the way
    libhdf5 does and requires every step to advance."""
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        at = data.find(b"GCOL\x01")
        while at >= 0:
            (size,) = struct.unpack_from("<Q", data, at + 8)
            end = min(at + size, len(data))
            pos = at + 16
            while pos + 16 <= end:
                index, _, _, length = struct.unpack_from("<HHIQ", data, pos)
                step = length if index == 0 else 16 + (length + 7) // 8 * 8
                if step <= 0:
                    raise RecordingFileError(path, f"corrupt HDF5 file (a global heap object at byte {pos} is empty, "
                                                   "which would make libhdf5 loop)")
                pos += step
            at = data.find(b"GCOL\x01", at + 4)


class Hdf5Reader(EpisodeReader):
    """Reads a simreel HDF5 recording. Raises `RecordingFileError` for anything else."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise not_a_file(self.path)
        if read_head(self.path, len(HDF5_MAGIC)) != HDF5_MAGIC:
            raise RecordingFileError(self.path, "not an HDF5 file")
        self.live = being_written(self.path)
        """A writer (in any process) is still writing the file: it holds the episodes committed so far."""
        with CommitLock.reading(partial_dir(self.path), self.path) if self.live else nullcontext():
            self._file = open_hdf5(self.path)
            try:
                self.meta = self._read_meta()
                self.fields = episode_fields(self.meta)
                self.kind = f"simreel HDF5 recording (format {self.meta.format_version})"
                self._groups: dict[int, Any] = {}
                self.episodes, self.damaged = self._scan()
            except BaseException:
                self._file.close()
                raise
        self.unfinished, self.notes = self._leftovers()

    def _read_meta(self) -> RecordingMeta:
        import h5py

        try:
            attrs = self._file.attrs
            if META_ATTR not in attrs:
                raise RecordingFileError(self.path, "an HDF5 file without simreel metadata (not a simreel recording)")
            if h5py.check_string_dtype(attrs.get_id(META_ATTR).dtype).length is None:
                _check_global_heaps(self.path)  # written by an earlier simreel: attributes in global heaps
            version = int(attrs.get(VERSION_ATTR, 0))
            text = decode_text(attrs[META_ATTR])
        except RecordingFileError:
            raise
        except H5PY_ERRORS as e:
            raise RecordingFileError(self.path, f"corrupt HDF5 file: its metadata cannot be read ({e})") from None
        if version > FORMAT_VERSION:
            raise RecordingFileError(
                self.path,
                f"format version {version} is newer than this simreel reads ({FORMAT_VERSION}); upgrade simreel",
            )
        try:
            return RecordingMeta.from_json(json_value(text, "its simreel metadata"))
        except (ValueError, TypeError) as e:  # MetadataError and JSONDecodeError are ValueErrors
            raise RecordingFileError(self.path, f"bad simreel metadata ({e})") from None

    def _scan(self) -> tuple[list[EpisodeMeta], list[str]]:
        """Every episode group at the root: the readable ones (their groups kept open in `_groups`), and what is
        wrong with the others."""
        try:
            names = list(self._file)
        except H5PY_ERRORS as e:
            raise RecordingFileError(self.path, f"corrupt HDF5 file: its list of episodes cannot be read ({e})") from None
        metas, damaged = [], []
        for name in names:
            try:
                meta = self._episode(name)
            except ValueError as e:
                damaged.append(f"{name}: {e}")
                continue
            if meta is not None:
                metas.append(meta)
        return sorted(metas, key=lambda m: m.index), damaged

    def _episode(self, name: str) -> EpisodeMeta | None:
        """The metadata of group `name` (its group kept in `_groups`); None for an object that is no episode;
        ValueError saying what is wrong with a damaged one."""
        import h5py

        index = group_index(name)
        try:
            group = self._file[name]
            if not isinstance(group, h5py.Group):
                return None
            attrs = group.attrs
            if EPISODE_ATTR not in attrs and index is None:
                return None  # a group some other tool added: not an episode
            if EPISODE_ATTR not in attrs:
                found = ", ".join(sorted(attrs)) or "none"
                raise ValueError(f"no {EPISODE_ATTR} attribute (attributes found: {found}); half written or damaged")
            meta = EpisodeMeta.from_json(json_value(decode_text(attrs[EPISODE_ATTR]), f"its {EPISODE_ATTR}"))
        except (RecordingFileError, ValueError):
            raise
        except H5PY_ERRORS as e:
            raise ValueError(f"cannot be read ({type(e).__name__}: {e})") from None
        if index is None or meta.index != index:
            raise ValueError(f"its metadata says episode {meta.index}, its name says otherwise")
        self._groups[index] = group
        return meta

    def _leftovers(self) -> tuple[list[str], list[str]]:
        """Episodes a killed writer left running, and notes on the files beside this one."""
        note = replacement_note(self.path)
        if note is not None:
            return [], [note]
        if self.live:
            return [], ["being written by a running recording: these are the episodes committed so far"]
        folder = partial_dir(self.path)
        running = _running_episodes(folder, committed={m.index for m in self.episodes})
        unfinished = [_describe_running(folder, index, line) for index, line in sorted(running.items())]
        unfinished += [f"episode {_scratch_index(s)} (a scratch file, {_scratch_steps(s)} step(s))"
                       for s in sorted(folder.glob("traj_*.h5")) if _scratch_index(s) not in running]
        stale = _sidecar_disagreement(self.path, self.meta, self.episodes)
        if stale is None:
            return unfinished, []
        return unfinished, [f"its JSON sidecar (for ManiSkill's tools) {stale}; `simreel recover {self.path}` rewrites it"]

    # ---------------------------------------------------------------- data
    def open_episode(self, index: int) -> Hdf5Rows:
        """Episode `index`, its datasets checked against the layout (names, dtypes, shapes, row counts; none read)."""
        self.check_open()
        meta = self.episode_meta(index)
        group = self._groups[index]
        where = group_name(index)
        try:
            held = datasets_below(group)
            names = {f.name: self._dataset(held, group, f.name) for f in self.fields}
            datasets = {f.name: self._field(where, f, names[f.name], _member(held, group, names[f.name]), meta.length)
                        for f in self.fields}
            unlisted = unlisted_datasets_problem(where, held, names.values(), why="a damaged or altered file")
        except H5PY_ERRORS as e:
            raise RecordingFileError(self.path, f"{where} is corrupt: its structure cannot be read ({e})") from None
        if unlisted:
            raise RecordingFileError(self.path, unlisted)
        return Hdf5Rows(self.path, meta, self.fields, datasets)

    def _dataset(self, held: dict[str, Any], group: Any, field: str) -> str:
        """Where `field` is in `group` (whose datasets are `held`, `datasets_below`): ManiSkill's layout, or simreel's
        format-1 name (a bare-array observation as ``obs/<obs mode>``)."""
        name = dataset_name(field, self.meta)
        return name if name in held or name in group or field not in held and field not in group else field

    def _field(self, where: str, spec: FieldSpec, name: str, ds: Any, steps: int) -> Any:
        """`ds`, what episode group `where` holds at `name` (`_member`), as the dataset of field `spec`, checked against
        the layout (not read)."""
        import h5py

        if not isinstance(ds, h5py.Dataset):
            raise RecordingFileError(self.path, f"{where} lacks {name}, which the recording's layout lists")
        want = (spec.row_count(steps), *spec.shape)
        if ds.dtype != np.dtype(spec.dtype) or ds.shape != want:
            raise RecordingFileError(
                self.path, f"{where}/{name} is {ds.dtype} {ds.shape}, the layout says {spec.dtype} {want}"
            )
        return ds

    def close(self) -> None:
        self.closed = True
        self._groups.clear()
        self._file.close()


class Hdf5Rows(EpisodeRows):
    """An episode held in one HDF5 group (simreel's recordings and ManiSkill's files), read by h5py slicing: a block
    reads only the chunks holding its rows, and libhdf5 checks each against its Fletcher-32 checksum as it reads it.

    Args:
        datasets: field name -> its h5py dataset, already checked against the field table (T or T+1 rows).
    """

    def __init__(self, path: Path, meta: EpisodeMeta, fields: Sequence[FieldSpec], datasets: dict[str, Any]) -> None:
        super().__init__(meta, fields)
        self.path = path
        self.datasets = datasets

    def reset(self) -> StepBlock:
        return StepBlock.of({f.name: self._read(f.name, 0, 1) for f in self.fields if f.per_state})

    def steps(self, start: int, stop: int) -> StepBlock:
        return StepBlock.of({f.name: self._read(f.name, start + f.per_state, stop + f.per_state) for f in self.fields})

    def steps_of(self, names: Collection[str], start: int, stop: int) -> StepBlock:
        wanted = set(names)
        return StepBlock.of({f.name: self._read(f.name, start + f.per_state, stop + f.per_state) for f in self.fields
                             if f.name in wanted})

    def _read(self, name: str, start: int, stop: int) -> np.ndarray:
        ds = self.datasets[name]
        if not ds.id.valid:  # its file was closed by the reader
            raise closed_reader(self.path)
        try:
            return ds[start:stop]
        except H5PY_ERRORS as e:
            raise RecordingFileError(
                self.path, f"{ds.name.lstrip('/')} is corrupt: its data fails its checksum or cannot be decompressed ({e})"
            ) from None


# ------------------------------------------------------------------------------------- the JSON sidecar
_SIDECAR_USED = ("episode_id", "episode_seed", "control_mode", "elapsed_steps")
"""The keys of a sidecar's episode entry that ManiSkill's tools go by (with `reset_kwargs`' seed and options): which
group to read, the seed to reset with, the control mode of its actions, how many steps it has."""


def _sidecar_disagreement(path: Path, meta: RecordingMeta, episodes: list[EpisodeMeta]) -> str | None:
    """How the JSON sidecar beside the recording `path` disagrees with what the .h5 holds (`meta`, `episodes`), in
    what ManiSkill's tools take from it instead of the .h5 (env id and modes, the episodes listed, their seeds,
    reset options, control mode and length), as text following "its JSON sidecar"; None when it agrees, or there is
    none (simreel reads the .h5 alone). The sidecar the .h5 should have is the one simreel writes for it
    (`sidecar_document`), so a sidecar left from another recording, one that lags, or an edited one is told apart
    from a current one by the writer's own rule."""
    try:
        found = json_value(sidecar_path(path).read_bytes(), "it")
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as e:
        return f"cannot be read ({e})"
    want = sidecar_document(meta, episodes)
    if not isinstance(found, dict) or not isinstance(found.get("episodes"), list) \
            or not isinstance(found.get("env_info"), dict):
        return "is no ManiSkill sidecar (no env_info and episodes list)"
    return _env_disagreement(found["env_info"], want["env_info"]) or _episodes_disagreement(found["episodes"],
                                                                                            want["episodes"])


def _env_disagreement(found: dict[str, Any], want: dict[str, Any]) -> str | None:
    """Where the sidecar's `env_info` names another env id, obs mode or control mode than the .h5's (`want`)."""
    kwargs = found.get("env_kwargs") if isinstance(found.get("env_kwargs"), dict) else {}
    pairs = [("env_info.env_id", found.get("env_id"), want["env_id"])]
    pairs += [(f"env_info.env_kwargs.{k}", kwargs.get(k), want["env_kwargs"].get(k)) for k in ("obs_mode", "control_mode")]
    return _first_difference(pairs)


def _episodes_disagreement(found: list[Any], want: list[dict[str, Any]]) -> str | None:
    """Where the sidecar's episode list is not the .h5's (`want`), entries matched by episode id (ManiSkill's tools
    read group ``traj_<episode_id>``, in any order): episodes the .h5 holds that it does not list, ones it lists that
    the .h5 lacks, or the first entry whose seed, reset seed or options, control mode or length differ."""
    listed = {e.get("episode_id"): (i, e) for i, e in enumerate(found) if isinstance(e, dict)}
    held = {e["episode_id"]: e for e in want}
    foreign = [i for i in listed if i not in held]
    if foreign:
        shown = ", ".join(f"traj_{i}" for i in foreign[:3])
        return f"lists {len(found)} episodes, {len(foreign)} of them not in the .h5 ({shown}: ManiSkill's tools fail there)"
    if len(listed) < len(held):
        return f"lists {len(listed)} of the {len(held)} episodes"
    for index, expected in held.items():
        i, entry = listed[index]
        differs = _first_difference(_entry_pairs(f"episodes[{i}]", entry, expected))
        if differs:
            return differs
    return None


def _entry_pairs(where: str, found: dict[str, Any], want: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    """(key, sidecar's value, .h5's value) of each key of episode entry `found` that ManiSkill's tools use
    (`_SIDECAR_USED`, `reset_kwargs`' seed and options), against the .h5's entry `want`."""
    reset = found.get("reset_kwargs") if isinstance(found.get("reset_kwargs"), dict) else {}
    pairs = [(f"{where}.{k}", found.get(k), want.get(k)) for k in _SIDECAR_USED]
    return pairs + [(f"{where}.reset_kwargs.seed", reset.get("seed"), want["reset_kwargs"].get("seed")),
                    (f"{where}.reset_kwargs.options", reset.get("options") or {}, want["reset_kwargs"].get("options") or {})]


def _first_difference(pairs: list[tuple[str, Any, Any]]) -> str | None:
    """``says <key> <sidecar's value> where the .h5 says <its value>`` for the first (key, sidecar's, .h5's) of
    `pairs` whose values differ (compared as JSON: the sidecar's were read from it); None when none do."""
    for key, got, expected in pairs:
        expected = json.loads(json.dumps(expected, default=json_default))
        if got != expected:
            return f"says {key} {json.dumps(got, default=str)} where the .h5 says {json.dumps(expected)}"
    return None


def unlisted_datasets_problem(where: str, held: Iterable[str], listed: Iterable[str], *, why: str) -> str | None:
    """What is wrong with an episode group `where` whose datasets (`held`, paths below the group) include some that no
    field of the layout reads (`listed`: the fields' dataset paths), naming them and saying `why` they are there and
    what to do; None when there are none. A reader refuses such an episode rather than read it: its copy would lack
    them and a check would pass them unchecked (the one rule of both HDF5 readers, simreel's and ManiSkill's)."""
    extra = sorted(set(held) - set(listed))
    if not extra:
        return None
    shown = ", ".join(extra[:4]) + (f" and {len(extra) - 4} more" if len(extra) > 4 else "")
    return f"{where} holds {shown}, which the recording's layout does not list ({why})"


def datasets_below(group: Any) -> dict[str, Any]:
    """Every dataset below `group` by its path relative to the group (h5py datasets, not read), as h5py's
    ``visititems`` finds them (each object once, links not followed; a name that is no UTF-8 as bytes). The walk asks
    libhdf5 for each object's kind (~0.2 ms for an episode group of 16 datasets, where ``visititems`` builds an h5py
    object of every member: ~2.4 ms) and opens only the datasets; `Hdf5Reader.open_episode` takes ~2 ms with it,
    ~6.3 ms before, a cost every episode a reader opens pays."""
    import h5py

    kinds: dict[bytes, int] = {}
    h5py.h5o.visit(group.id, lambda name, info: kinds.__setitem__(name, info.type), info=True)
    return {_text(name): h5py.Dataset(h5py.h5d.open(group.id, name))
            for name, kind in kinds.items() if kind == h5py.h5o.TYPE_DATASET}


def _member(held: dict[str, Any], group: Any, name: str) -> Any:
    """What `group` holds at path `name`: its dataset found by the walk (`held`, `datasets_below`), else what h5py
    finds there (a link the walk does not follow, a group, or None)."""
    ds = held.get(name)
    return group.get(name) if ds is None else ds


def _text(name: bytes) -> str | bytes:
    """An HDF5 link name as h5py names it: text where it is UTF-8, else the bytes."""
    try:
        return name.decode("utf-8")
    except UnicodeDecodeError:
        return name


def _scratch_index(path: Path) -> int:
    return group_index(path.name.split(".", 1)[0]) or 0


def _running_episodes(folder: Path, committed: set[int]) -> dict[int, dict[str, Any]]:
    """The episodes a writer's journal (`running_journal`) says began, neither discarded nor committed: index ->
    its line. A line cut short by a crash names no episode and is skipped."""
    try:
        lines = running_journal(folder).read_text(errors="replace").splitlines()
    except OSError:
        return {}
    running: dict[int, dict[str, Any]] = {}
    for text in lines:
        try:
            line = json_value(text, "a line")
            if "began" in line:
                running[int(line["began"])] = line
            else:
                running.pop(int(line["ended"]), None)
        except (ValueError, TypeError, KeyError):
            continue
    return {index: line for index, line in running.items() if index not in committed}


def _describe_running(folder: Path, index: int, line: dict[str, Any]) -> str:
    """What a killed writer's journal says about the episode it was running."""
    scratch = scratch_path(folder, index)
    steps = f"{_scratch_steps(scratch)} step(s) in a scratch file" if scratch.exists() else "its steps were in memory"
    return f"episode {index} (env {line.get('env_idx', 0)}, seed {line.get('seed')}; {steps})"


def _scratch_steps(scratch: Path) -> str:
    """How many steps a killed writer's scratch file holds ("?" when it cannot be read)."""
    import h5py

    try:
        with h5py.File(scratch, "r", locking=False) as f:
            return str(f["traj/rewards"].shape[0]) if "traj/rewards" in f else "0"
    except H5PY_ERRORS:
        return "?"
