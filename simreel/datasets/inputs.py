"""Which recording files a command's inputs name: files, folders (searched below for .h5/.hdf5/.mcap files) and glob
patterns; and how a summary shows a path."""

from __future__ import annotations

import glob
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from simreel.errors import UsageError
from simreel.formats import HDF5_SUFFIXES, MCAP_SUFFIXES, recording_files
from simreel.io.paths import file_key, is_symlink_loop, refuse_empty
from simreel.io.staging import is_staging_path

__all__ = ["RECORDING_SUFFIXES", "expand_inputs", "file_identity", "shown_path"]

RECORDING_SUFFIXES = (*HDF5_SUFFIXES, *MCAP_SUFFIXES)


def file_identity(path: str | os.PathLike[str]) -> tuple[int, int]:
    """What says a recording is the one seen before (by a report, a plan, another machine): the size of its files
    and the latest of their modification times in ns — the recording file and the files its format keeps beside it
    (an HDF5 recording's JSON sidecar, which lists a ManiSkill file's episodes and their seeds). Raises `OSError`
    when there is no such file."""
    st = os.stat(path)
    size, mtime_ns = st.st_size, st.st_mtime_ns
    for side in _side_files(path):
        if side.is_file():
            side_st = side.stat()
            size, mtime_ns = size + side_st.st_size, max(mtime_ns, side_st.st_mtime_ns)
    return size, mtime_ns


def _side_files(path: str | os.PathLike[str]) -> list[Path]:
    """The files beside the recording `path` that are part of it: those beside the name given, which a reader reads
    (a ManiSkill file's sidecar beside a link to it); for a link with none beside it, those of its target."""
    beside = recording_files(path)[1:]
    return beside if any(p.exists() for p in beside) else recording_files(os.path.realpath(path))[1:]


def _is_pattern(spec: str) -> bool:
    return any(ch in spec for ch in "*?[")


def _found_in(spec: str) -> list[Path]:
    """Recording files below a folder or matching a glob (not the scratch files of running HDF5 recordings). A
    symbolic link loop named as a recording is one too: its reader says what it is, where skipping it would hide it."""
    p = Path(spec)
    found = p.rglob("*") if p.is_dir() else (Path(x) for x in glob.glob(spec, recursive=True))
    return sorted(x for x in found if (x.is_file() or is_symlink_loop(x)) and x.suffix.lower() in RECORDING_SUFFIXES
                  and not any(part.endswith(".partial") for part in x.parts))


def _without_staged(found: list[Path]) -> tuple[list[Path], list[Path]]:
    """(recordings, staged outputs) of the files a scan found: a file under a merge's or filter's staging name is
    an output not yet checked (being made, or left by a run that was killed), never a recording to read."""
    staged = [f for f in found if is_staging_path(f)]
    return [f for f in found if f not in staged], staged


def _say_skipped(staged: Sequence[Path]) -> None:
    """One line on stderr naming the staged outputs a scan skipped (if any), and what to do with them."""
    if not staged:
        return
    names = ", ".join(shown_path(f) for f in staged)
    sys.stderr.write(f"simreel: warning: skipped {names}: unchecked output(s) of a merge or filter that was "
                     "interrupted (or still runs); the next merge or filter of the same output removes them, or once "
                     "none runs delete them and the files beside them of the same name (name one to inspect it)\n")


def expand_inputs(specs: Sequence[str | Path]) -> list[tuple[Path, bool]]:
    """(absolute path, named explicitly) for every input file: a file as given; a folder or glob as the
    recordings it holds (`UsageError` when it holds none), without the staged outputs of a merge or filter, which
    are named once on stderr. Each file once, in the order given. A path that names no readable file (missing, a
    symbolic link loop) is kept for its reader to say why; an empty one is `UsageError`. One file reached by two paths
(a hard or symbolic link, another spelling: `file_key`) is read once."""
    out: dict[tuple[int, int] | Path, tuple[Path, bool]] = {}
    skipped: dict[Path, None] = {}
    for spec in map(str, specs):
        refuse_empty(spec, what="recording", instead="name the files, folders or patterns to read")
        if Path(spec).is_dir() or (_is_pattern(spec) and not Path(spec).exists()):
            found, staged = _without_staged(_found_in(spec))
            skipped.update(dict.fromkeys(staged))
            if not found:
                _say_skipped(list(skipped))
                kind = "folder" if Path(spec).is_dir() else "pattern"
                raise UsageError(f"{spec}: no recordings (.h5, .hdf5, .mcap) found in this {kind}")
            out.update((file_key(f), (Path(os.path.abspath(f)), False)) for f in found if file_key(f) not in out)
        else:
            out.setdefault(file_key(spec), (Path(os.path.abspath(spec)), True))
    _say_skipped(list(skipped))
    return list(out.values())


def shown_path(path: str | Path) -> str:
    """`path` as a summary shows it: relative to the working folder when it is below it."""
    rel = os.path.relpath(path)
    return str(path) if rel.startswith("..") else rel
