"""A small file system of its own for disk-full tests: a tmpfs where this process may mount one, else an ext2 loop
image; the test is skipped where neither can be mounted (not root, no mount namespace). Removed afterwards."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


def _run(*command: str) -> subprocess.CompletedProcess:
    return subprocess.run(list(command), capture_output=True, text=True)


@contextmanager
def small_disk(where: Path, kib: int) -> Iterator[Path]:
    """A mounted file system of `kib` KiB at `where/disk` (skips the test when none can be mounted)."""
    mount = where / "disk"
    mount.mkdir()
    tried = _run("mount", "-t", "tmpfs", "-o", f"size={kib}k", "tmpfs", str(mount)) if shutil.which("mount") else None
    if tried is None or tried.returncode != 0:
        image = where / "disk.img"
        with open(image, "wb") as fh:
            fh.truncate(max(kib, 256) * 1024)
        made = _run("mke2fs", "-q", "-F", "-m", "0", str(image)) if shutil.which("mke2fs") else None
        tried = _run("mount", "-o", "loop", str(image), str(mount)) if made and made.returncode == 0 else None
        if tried is None or tried.returncode != 0:
            pytest.skip("cannot mount a small file system here (needs root: mount -t tmpfs, or a loop device)")
    try:
        yield mount
    finally:
        _run("umount", str(mount))


def fill(disk: Path, leave_kib: int) -> None:
    """Fill `disk` with another file (`filler`, `filler1`, ...) until about `leave_kib` KiB are left free."""
    free = shutil.disk_usage(disk).free
    size = max(0, free - leave_kib * 1024)
    name = "filler" + str(len(list(disk.glob("filler*"))) or "")
    with open(disk / name, "wb") as fh:
        try:
            fh.write(b"\0" * size)
        except OSError:  # exactly full
            pass
