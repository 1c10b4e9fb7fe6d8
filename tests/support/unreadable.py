"""Paths that name no readable file, made for real on the test's file system: a symbolic link loop, and a file this
user may not read (with, for root, the command prefix that makes its mode bite)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

__all__ = ["link_loop", "unreadable_copy"]

_READ_ANYTHING = "-dac_override,-dac_read_search"
"""The capabilities that let root read any file whatever its mode: dropped, a file of mode 000 bites root too."""
_DENIED = 13
"""The exit status of the probe (`_probe`) that could not read the file: permission denied, as wanted."""
_PROBE = ("import sys\ntry:\n    open(sys.argv[1], 'rb').close()\nexcept PermissionError:\n"
          f"    sys.exit({_DENIED})\n")


def link_loop(path: Path) -> Path:
    """`path` made a symbolic link loop: a link to a link (beside it, ``.other`` before its suffix) that links back."""
    other = path.with_name(f"{path.stem}.other{path.suffix}")
    other.symlink_to(path.name)
    path.symlink_to(other.name)
    return path


def unreadable_copy(src: Path, dst: Path) -> list[str]:
    """Copy `src` to `dst` (and an HDF5 recording's JSON sidecar beside it, readable), take every permission from
    `dst` and return the command prefix under which a process may not read it: for root, `setpriv` without the
    capabilities that read anything; for another user, none. `pytest.skip` where a process can still read it that way
    (no setpriv, or one that cannot drop them)."""
    shutil.copy(src, dst)
    if src.with_suffix(".json").is_file():
        shutil.copy(src.with_suffix(".json"), dst.with_suffix(".json"))
    dst.chmod(0)
    prefix = []
    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            pytest.skip("root reads any file, and setpriv (util-linux), which drops that power, is not installed")
        prefix = [setpriv, f"--bounding-set={_READ_ANYTHING}", f"--inh-caps={_READ_ANYTHING}"]
    probe = subprocess.run([*prefix, sys.executable, "-c", _PROBE, str(dst)], capture_output=True, text=True)
    if probe.returncode != _DENIED:
        pytest.skip(f"a process here can still read a file of mode 000 (probe: exit {probe.returncode}, "
                    f"{probe.stderr.strip()[-200:]!r})")
    return prefix
