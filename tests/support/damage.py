"""Damaged recordings for the integrity tests: byte offsets of an HDF5 dataset's stored bytes, a file as simreel's
first HDF5 format wrote it (attributes in global heaps, no checksums), and `sweep`, which damages a file one way at
many offsets and says, for each, what a reader made of it.

Run as a script (`python damage.py FILE flip|zero64 STEP`), it prints one line per offset, `OFFSET OUTCOME`, and a
last line `done`; the tests run it in a child process with a time limit, so a reader that hangs shows up as the
offset it hung on.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

from simreel.model.episode import Episode
from simreel.model.meta import RecordingMeta

__all__ = ["stored_bytes", "corrupt_chunk", "write_format1", "sweep"]


def stored_bytes(path: Path, dataset: str) -> tuple[int, int]:
    """(file offset, size) of the stored bytes of `dataset` (its one chunk, or its contiguous data)."""
    import h5py

    with h5py.File(path, "r", locking=False) as f:
        ds = f[dataset]
        if ds.chunks:
            info = ds.id.get_chunk_info(0)
            return info.byte_offset, info.size
        return ds.id.get_offset(), ds.id.get_storage_size()


def corrupt_chunk(path: Path, dataset: str, chunk: int, rows: int = 5) -> None:
    """Store `dataset` again in chunks of `rows` rows, each with its checksum, and flip one bit in the middle of
    chunk `chunk` (rows `chunk * rows` on): the blocks before it read, the one holding it fails its checksum."""
    import h5py

    with h5py.File(path, "r+") as f:
        data = f[dataset][()]
        del f[dataset]
        f.create_dataset(dataset, data=data, chunks=(rows, *data.shape[1:]), fletcher32=True)
        info = f[dataset].id.get_chunk_info(chunk)
    damaged = bytearray(path.read_bytes())
    damaged[info.byte_offset + info.size // 2] ^= 0x10
    path.write_bytes(damaged)


def write_format1(path: Path, meta: RecordingMeta, episodes: list[Episode]) -> Path:
    """`episodes` written as simreel's first HDF5 writer did: default h5py layout, contiguous datasets, JSON
    attributes as variable-length strings (stored in global heaps)."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["simreel_format_version"] = 1
        f.attrs["simreel_meta"] = json.dumps(meta.to_json())
        for ep in episodes:
            g = f.create_group(f"traj_{ep.meta.index}")
            for name, a in ep.fields().items():
                g.create_dataset(name, data=a)
            g.attrs["simreel_episode"] = json.dumps(ep.meta.to_json())
    return path


def _outcome(path: Path, want: dict[int, Episode], meta_json: dict) -> str:
    """What a reader made of the damaged file `path`: refused / damaged / corrupt / ok, or SILENT (it returned
    something other than what was written, without a word) or BUG (an error that is not a `SimreelError`)."""
    from simreel.errors import SimreelError
    from simreel.formats import open_reader

    try:
        with open_reader(path) as r:
            if r.meta.to_json() != meta_json:
                return "SILENT metadata"
            seen = []
            for m in r.episodes:
                try:
                    got = r.read_episode(m.index)
                except SimreelError:
                    seen.append("corrupt")
                    continue
                if m.index not in want or not _same(got, want[m.index]):
                    return f"SILENT episode {m.index}"
                seen.append("ok")
            missing = set(want) - {m.index for m in r.episodes}
            if missing and len(r.damaged) < len(missing):
                return f"SILENT missing {sorted(missing)}"
            return "damaged" if r.damaged else ("corrupt" if "corrupt" in seen else "ok")
    except SimreelError:
        return "refused"
    except Exception as e:  # noqa: BLE001 - what the sweep looks for
        return f"BUG {type(e).__name__}: {e}"


def _same(a: Episode, b: Episode) -> bool:
    if a.meta != b.meta:
        return False
    fa, fb = a.fields(), b.fields()
    return fa.keys() == fb.keys() and all(fa[k].dtype == fb[k].dtype and fa[k].tobytes() == fb[k].tobytes() for k in fa)


def sweep(path: Path, how: str, step: int) -> None:
    """Damage a copy of `path` at every `step`-th offset (`flip`: invert one byte; `zero64`: zero 64 bytes) and
    print each outcome."""
    from simreel.formats import open_reader

    data = path.read_bytes()
    with open_reader(path) as r:
        meta_json = r.meta.to_json()
        want = {m.index: r.read_episode(m.index) for m in r.episodes}
    with tempfile.TemporaryDirectory() as folder:
        damaged = Path(folder) / path.name
        for offset in range(0, len(data), step):
            copy = bytearray(data)
            if how == "flip":
                copy[offset] ^= 0xFF
            else:
                copy[offset : offset + 64] = bytes(min(64, len(data) - offset))
            damaged.write_bytes(copy)
            print(offset, _outcome(damaged, want, meta_json), flush=True)
    print("done", flush=True)


if __name__ == "__main__":
    sweep(Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]))
    sys.exit(0)
