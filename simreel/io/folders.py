"""A folder an export writes (a LeRobot dataset), written as one unit: under a hidden name beside it first
(``.NAME.PID@HOST.partial/``), and given its name only once complete (`staged_folder`), so a run stopped half way
(an error, Ctrl-C, a full disk, kill -9) never leaves a half folder under the name. An old folder is replaced only
with ``overwrite``, and only one that `looks_ours` says this kind of writer wrote: ``--overwrite`` never removes a
folder of something else (a typo'd home folder)."""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from simreel.errors import UsageError
from simreel.io.targets import (
    OVERWRITE_HINT,
    check_name_lengths,
    made_by_gone_process,
    process_tag,
    short_name,
)

__all__ = ["check_folder_output", "staged_folder"]


def check_folder_output(path: str | Path, *, overwrite: bool, looks_ours: Callable[[Path], bool], kind: str) -> Path:
    """`UsageError` unless a new folder `kind` ("LeRobot dataset") can be written at `path`: its parent is a folder,
    and where `path` exists, it is a folder `looks_ours` and `overwrite` is given. Touches nothing."""
    p = Path(path)
    check_name_lengths(p)
    if not p.parent.is_dir():
        raise UsageError(f"{p}: no folder {p.parent} to write it in; create it first")
    if p.exists() or p.is_symlink():
        if not p.is_dir() or p.is_symlink():
            raise UsageError(f"{p} exists and is no folder; name a new folder for the {kind}")
        if not looks_ours(p):
            if not any(p.iterdir()):
                return p  # an empty folder: nothing to lose
            raise UsageError(f"{p} is a folder that holds no {kind}; it is kept, even with --overwrite: name a new "
                             "folder, or remove this one yourself")
        if not overwrite:
            raise UsageError(f"{p} already exists; {OVERWRITE_HINT}")
    return p


@contextlib.contextmanager
def staged_folder(path: Path, *, overwrite: bool, looks_ours: Callable[[Path], bool], kind: str) -> Iterator[Path]:
    """A new empty folder to write `path` through, beside it; when the block ends without error it takes `path`'s
    name (the old folder there, checked again by `check_folder_output`, moved aside and then removed), and when the
    block raises it is removed. Partial folders that runs of this machine left (killed ones) are removed first."""
    prefix = f".{short_name(path.name)}."
    for left in path.parent.glob(f"{prefix}*.partial"):
        tag = left.name[len(prefix):-len(".partial")].rsplit(".", 1)[0]
        if made_by_gone_process(tag):
            shutil.rmtree(left, ignore_errors=True)
    partial = Path(tempfile.mkdtemp(prefix=f"{prefix}{process_tag()}.", suffix=".partial", dir=path.parent))
    partial.chmod(0o755)  # as mkdir makes it under the usual umask: mkdtemp's 0700 hides it from other users
    try:
        yield partial
        check_folder_output(path, overwrite=overwrite, looks_ours=looks_ours, kind=kind)
        old = partial.with_name(partial.name[: -len(".partial")] + ".old")
        if path.is_dir():
            path.rename(old)
        partial.rename(path)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        if partial.exists():
            shutil.rmtree(partial, ignore_errors=True)
