"""The one rule for every file simreel writes: never replace anything without ``--overwrite``.

Every command that writes (a recording and the files its format keeps beside it, a JSON report, an .rrd)
checks its outputs with `check_output` before any slow work, and writes small files with
`write_text_atomic`, so a reader never sees half a file. Recording formats add their side files and their
own conditions (an MCAP file another process is writing) in `simreel.formats.check_writable`.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import glob
import hashlib
import os
import socket
import stat
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from simreel.errors import UsageError
from simreel.io.paths import SYMLINK_LOOP, file_key, is_symlink_loop, real_path
from simreel.options.checks import check_flag

__all__ = ["check_output", "check_distinct", "write_text_atomic", "open_text_atomic", "staged_output",
           "move_into_place", "process_alive", "process_tag", "made_by_gone_process", "short_name", "OVERWRITE_HINT",
           "NAME_MAX"]

OVERWRITE_HINT = "pass --overwrite to replace it (overwrite=True from Python)"
"""How every refusal to replace a file says what to do: the CLI's option and the Python API's keyword."""
NAME_MAX = 255
"""The longest file or folder name, in bytes, where the file system does not say (Linux's NAME_MAX: ext4, xfs,
btrfs, tmpfs); a longer one is refused by every call that names it (ENAMETOOLONG)."""


def check_output(path: str | Path, *, overwrite: bool, side_paths: Iterable[Path] = (), option: str = "") -> Path:
    """Raise `UsageError` unless a new file can be written at `path` (and its `side_paths`); touch nothing.

    Refused: a name in `path`, or a side file's name, longer than the file system takes (`check_name_lengths`);
    `path` is a folder or runs into a symbolic link loop, or it or a side path is a FIFO, device or socket (even with
    `overwrite`: nothing can be written through one, and a pipe or device is not replaced by a file);
    its folder does not exist, is not a folder or is not writable; and, without `overwrite`, `path` or one of
    `side_paths` already exists. `option` names the CLI option in messages (``--report``). Returns `path` as a
    `Path`. `overwrite` must be a bool: ``overwrite="no"`` would count as yes and replace the file.
    """
    check_flag("overwrite", overwrite)
    p = Path(path)
    label = f"{option} {p}" if option else str(p)
    side_paths = list(side_paths)
    check_name_lengths(p, side_paths, label=label)
    if p.is_dir():
        raise UsageError(f"{label}: that is a folder; name the file to write")
    if is_symlink_loop(p):
        raise UsageError(f"cannot write {label}: {SYMLINK_LOOP}")
    _refuse_special_files(p, side_paths, label)
    folder = real_path(p).parent
    if not folder.exists():
        raise UsageError(f"cannot write {p}: folder {folder} does not exist")
    if not folder.is_dir():
        raise UsageError(f"cannot write {p}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"cannot write {p}: folder {folder} is not writable")
    if overwrite:
        return p
    if p.exists() or p.is_symlink():
        raise UsageError(f"{p} already exists; {OVERWRITE_HINT}")
    for side in side_paths:
        if side.exists() or side.is_symlink():
            raise UsageError(f"{side} already exists and writing {p.name} would replace it; {OVERWRITE_HINT}")
    return p


def _refuse_special_files(path: Path, side_paths: Iterable[Path], label: str) -> None:
    """`UsageError` when `path` or one of its `side_paths`, through their links, is a FIFO, a device or a socket, even
    with overwrite: an output is written beside its path and renamed over it, which would replace the pipe or device
    itself (as root, /dev/null); and asking whether a writer holds a FIFO waits for its other end."""
    for named in (path, *side_paths):
        try:
            mode = named.stat().st_mode
        except OSError:  # missing, a dangling link: nothing there to replace
            continue
        if not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
            which = "it is" if named == path else f"{named}, which writing it replaces, is"
            raise UsageError(f"cannot write {label}: {which} a pipe, device or socket, not a regular file; simreel "
                             "writes whole files, so name a file to write")


def check_name_lengths(path: Path, side_paths: Iterable[Path] = (), *, label: str = "") -> None:
    """`UsageError` when a name in `path` (a folder's, or the file's), or the name of one of the `side_paths` its
    writer keeps beside it, is longer than the file system takes: one line before any work, where the first call
    that named it would fail with ENAMETOOLONG. The limit is the folder's (`os.pathconf`), else `NAME_MAX`."""
    label = label or str(path)
    for part in path.parent.parts:
        _check_name_length(part, NAME_MAX, label, "a folder name in it")
    limit = _name_max(path.parent)
    _check_name_length(path.name, limit, label, "its name")
    for side in side_paths:
        _check_name_length(side.name, limit, label, f"the name of the {side.suffix} file beside it")


def _check_name_length(name: str, limit: int, label: str, what: str) -> None:
    """`UsageError` when `name` is longer than `limit` bytes, saying `what` it is of `label`."""
    size = len(os.fsencode(name))
    if size > limit:
        raise UsageError(f"cannot write {label}: {what} is {size} bytes long, and the file system takes names of "
                         f"{limit} bytes at most; choose a shorter name")


def _name_max(folder: Path) -> int:
    """The longest name `folder`'s file system takes, in bytes; `NAME_MAX` where it cannot be asked (no such folder)."""
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return NAME_MAX


def check_distinct(outputs: Mapping[str, Iterable[str | Path]], input_files: Sequence[str | Path], *,
                   input_label: str = "the input") -> None:
    """Raise `UsageError` when two outputs are one file, or an output is one of the input's files (`file_key`: a hard
    link of it too).

    `outputs` maps an option (``-o``, ``--report``) to the files it writes (a recording: the file and its side
    files); `input_files` are the input and the files beside it (`simreel.formats.recording_files`)."""
    seen: dict[tuple[int, int] | Path, str] = {}
    for k, p in enumerate(input_files):
        seen[file_key(p)] = input_label if k == 0 else f"a file of {input_label}"
    for option, paths in outputs.items():
        for path in paths:
            key = file_key(path)
            if key in seen:
                raise UsageError(f"{option} {path} is {seen[key]}; write it to another file")
            seen[key] = f"also written by {option}"


@contextmanager
def open_text_atomic(path: str | Path) -> Iterator[IO[str]]:
    """A text file to write `path` through: a temporary file in the same folder, renamed to `path` when the block
    ends without error. A reader sees the old file or the whole new one, never a part; an interrupted write leaves
    no temporary file behind (a kill -9 leaves one, which the next write of `path` on this machine removes:
    `_temporary_file`)."""
    p = Path(path)
    fd, tmp = _temporary_file(p, ".tmp")
    held = os.dup(fd)  # keeps the file's lock (`_temporary_file`) until it is renamed, after `fh` is closed
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # as open() would make it: mkstemp's 0600 hides it from other users
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            yield fh
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        os.close(held)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write `text` to `path` at once (`open_text_atomic`)."""
    with open_text_atomic(path) as fh:
        fh.write(text)


@contextlib.contextmanager
def staged_output(path: Path, *, overwrite: bool, option: str = "") -> Iterator[Path]:
    """A temporary file to write `path` through: in the same folder, under a name no other run uses
    (``.NAME.PID@HOST.XXXXXXXX.partial.EXT``, the extension kept for writers that go by it, `_temporary_file`), moved
    to `path` when the block ends without error and removed when it raises (an error, a full disk, Ctrl-C, SIGTERM;
    after a kill -9, by the next run writing `path` on this machine). So `path` is never a
    part of a file, and an old one stays as it was until a whole new one replaces it. A symbolic link at `path` is
    replaced by the new file, as every writer of simreel replaces one: the file it leads to (another recording, say)
    stays as it was. Without `overwrite`, a file
    that appeared at `path` meanwhile (another run's) is not replaced: `UsageError`. `option` names the CLI option
    in messages (``--save``)."""
    from simreel.io.durable import is_storage_error, storage_error

    try:
        fd, name = _temporary_file(path, f".partial{path.suffix}")
    except OSError as e:
        if is_storage_error(e):
            raise storage_error(path, e, lost="nothing was written") from None
        raise
    partial = Path(name)
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # as open() would make it: mkstemp's 0600 hides it from other users
        yield partial
        _publish(partial, path, overwrite=overwrite, option=option)
    finally:
        partial.unlink(missing_ok=True)
        os.close(fd)  # and with it the file's lock (`_temporary_file`)


def _temporary_file(path: Path, suffix: str) -> tuple[int, str]:
    """A new temporary file to write `path` through (`tempfile.mkstemp`: open, its name no other run's), beside the
    file `path` names: ``.NAME.PID@HOST.XXXXXXXX`` + `suffix` (`process_tag`), locked (`flock`) for as long as the
    caller holds the descriptor. First the ones runs of this machine left there for the same `path` and `suffix`
    and never removed (a kill -9 runs no cleanup) are removed: those whose process is gone and whose lock is free
    (a PID another container reuses, which shares the host name, leaves its live file locked)."""
    prefix, folder = f".{short_name(path.name)}.", path.absolute().parent  # beside `path`, a link's too
    for leftover in folder.glob(glob.escape(prefix) + "*@*" + glob.escape(suffix)):
        tag, _, random = leftover.name[len(prefix):len(leftover.name) - len(suffix)].rpartition(".")
        if len(random) == _MKSTEMP_RANDOM and made_by_gone_process(tag):
            _remove_unlocked(leftover)
    fd, name = tempfile.mkstemp(prefix=f"{prefix}{process_tag()}.", suffix=suffix, dir=folder)
    with contextlib.suppress(OSError):  # a file system without locks: no leftover there is ever removed either
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd, name


def _remove_unlocked(leftover: Path) -> None:
    """Remove `leftover` unless a process holds its lock; nothing where it cannot be (another user's, in a shared
    folder: theirs to remove)."""
    with contextlib.suppress(OSError):
        fd = os.open(leftover, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # BlockingIOError: a live writer holds it
            leftover.unlink(missing_ok=True)
        finally:
            os.close(fd)


_MKSTEMP_RANDOM = 8
"""The characters `tempfile.mkstemp` puts between a prefix and a suffix."""
_NAME_KEPT = 100
"""A file name up to this long stays whole in its temporary file's name; a longer one is cut (`short_name`)."""


def short_name(name: str) -> str:
    """`name`, or where it is longer than `_NAME_KEPT`, its start and a digest of it: with the process tag and the
    rest, the name of a temporary file or a staged output (`simreel.io.staging.staging_path`) made from it
    stays under the file system's 255 bytes."""
    if len(name.encode()) <= _NAME_KEPT:
        return name
    digest = hashlib.sha1(name.encode()).hexdigest()[:12]
    return f"{name.encode()[:_NAME_KEPT - 13].decode(errors='ignore')}~{digest}"


def process_tag() -> str:
    """``PID@HOST``: this process and machine, in the names of the files a run writes before they are whole (a
    temporary file, a staged output), so that what a killed run left is known as such (`made_by_gone_process`)."""
    return f"{os.getpid()}@{socket.gethostname()}"


def made_by_gone_process(tag: str) -> bool:
    """Whether `tag` (`process_tag`) names a process of this machine that no longer runs: what it left is garbage.
    Never for another machine's process (it may be running: a shared folder), nor for what is no tag."""
    pid, at, host = tag.partition("@")
    return bool(at) and pid.isdigit() and host == socket.gethostname() and not process_alive(int(pid))


def process_alive(pid: int) -> bool:
    """Whether process `pid` runs on this machine (this one included; one that cannot be asked counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def _publish(partial: Path, path: Path, *, overwrite: bool, option: str) -> None:
    """Move the complete `partial` to `path` (`move_into_place`); `UsageError` when a file appeared there meanwhile."""
    try:
        move_into_place(partial, path, overwrite=overwrite)
    except FileExistsError:
        label = f"{option} {path}" if option else str(path)
        raise UsageError(f"{label}: a file appeared there while this one was written (another run?); it is kept; "
                         f"{OVERWRITE_HINT}") from None


def move_into_place(partial: Path, path: Path, *, overwrite: bool) -> None:
    """Move the complete file `partial` to `path`. Without `overwrite`, never over a file that is there:
    `FileExistsError` (a hard link fails if the name exists, where a check and a rename leave a moment for another
    run to write it; on a file system without hard links, a check and a rename)."""
    if overwrite:
        os.replace(partial, path)
        return
    try:
        os.link(partial, path)
    except FileExistsError:
        raise
    except OSError as e:
        if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV, errno.EMLINK):
            raise
        if path.exists() or path.is_symlink():
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(path)) from None
        os.replace(partial, path)
        return
    partial.unlink()


def _umask() -> int:
    """The process's umask: from /proc where there is one (reading it through `os.umask` means setting it, for a moment
    in which another thread's new file would get another mask), else through `os.umask`."""
    with contextlib.suppress(OSError, ValueError, StopIteration), open("/proc/self/status") as status:
        return int(next(line for line in status if line.startswith("Umask:")).split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
