"""The one rule for every file simreel writes: never replace anything without ``--overwrite``.

Every command that writes (a recording and the files its format keeps beside it, a JSON report, an .rrd)
checks its outputs with `check_output` before any slow work, and writes small files with
`write_text_atomic`, so a reader never sees half a file. Recording formats add their side files and their
own conditions (an MCAP file another process is writing) in `simreel.formats.check_writable`.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from simreel.errors import UsageError

__all__ = ["check_output", "check_distinct", "write_text_atomic", "open_text_atomic"]


def check_output(path: str | Path, *, overwrite: bool, side_paths: Iterable[Path] = (), option: str = "") -> Path:
    """Raise `UsageError` unless a new file can be written at `path` (and its `side_paths`); touch nothing.

    Refused: `path` is a folder; its folder does not exist, is not a folder or is not writable; and, without
    `overwrite`, `path` or one of `side_paths` already exists. `option` names the CLI option in messages
    (``--report``). Returns `path` as a `Path`.
    """
    p = Path(path)
    label = f"{option} {p}" if option else str(p)
    if p.is_dir():
        raise UsageError(f"{label}: that is a folder; name the file to write")
    folder = p.resolve().parent
    if not folder.exists():
        raise UsageError(f"cannot write {p}: folder {folder} does not exist")
    if not folder.is_dir():
        raise UsageError(f"cannot write {p}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"cannot write {p}: folder {folder} is not writable")
    if overwrite:
        return p
    if p.exists() or p.is_symlink():
        raise UsageError(f"{p} already exists; pass --overwrite to replace it")
    for side in side_paths:
        if side.exists() or side.is_symlink():
            raise UsageError(f"{side} already exists and writing {p.name} would replace it; "
                             "pass --overwrite to replace it")
    return p


def check_distinct(outputs: Mapping[str, Iterable[str | Path]], input_files: Sequence[str | Path], *,
                   input_label: str = "the input") -> None:
    """Raise `UsageError` when two outputs are one file, or an output is one of the input's files.

    `outputs` maps an option (``-o``, ``--report``) to the files it writes (a recording: the file and its side
    files); `input_files` are the input and the files beside it (`simreel.formats.recording_files`)."""
    seen: dict[Path, str] = {}
    for k, p in enumerate(input_files):
        seen[Path(p).resolve()] = input_label if k == 0 else f"a file of {input_label}"
    for option, paths in outputs.items():
        for path in paths:
            resolved = Path(path).resolve()
            if resolved in seen:
                raise UsageError(f"{option} {path} is {seen[resolved]}; write it to another file")
            seen[resolved] = f"also written by {option}"


@contextmanager
def open_text_atomic(path: str | Path) -> Iterator[IO[str]]:
    """A text file to write `path` through: a temporary file in the same folder, renamed to `path` when the block
    ends without error. A reader sees the old file or the whole new one, never a part; an interrupted write leaves
    no temporary file behind."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.resolve().parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # as open() would make it: mkstemp's 0600 hides it from other users
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            yield fh
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write `text` to `path` at once (`open_text_atomic`)."""
    with open_text_atomic(path) as fh:
        fh.write(text)


def _umask() -> int:
    """The process's umask: from /proc where there is one (reading it through `os.umask` means setting it, for a moment
    in which another thread's new file would get another mask), else through `os.umask`."""
    with contextlib.suppress(OSError, ValueError, StopIteration), open("/proc/self/status") as status:
        return int(next(line for line in status if line.startswith("Umask:")).split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
