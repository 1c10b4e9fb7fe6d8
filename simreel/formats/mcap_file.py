"""What simreel's MCAP writer and reader share: channel topics, metadata record names, the time base, the lock.

See `simreel.formats.mcap` for the layout of a recording.
"""

from __future__ import annotations

from pathlib import Path
from typing import IO

from simreel.episode import RecordingMeta

__all__ = [
    "MCAP_MAGIC",
    "COMPRESSIONS",
    "TOPICS",
    "META_RECORDING",
    "META_BEGIN",
    "META_EPISODE",
    "META_DISCARD",
    "WORLD_FRAME",
    "step_ns_of",
    "lock_file",
    "being_written",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
COMPRESSIONS = ("zstd", "lz4", "none")
TOPICS = {"reset": "/simreel/reset", "steps": "/simreel/steps", "tf": "/tf", "plots": "/plots", "log": "/log"}
META_RECORDING = "simreel"
"""The recording's metadata record; per episode i: `<META_BEGIN>.<i>`, `<META_EPISODE>.<i>`, `<META_DISCARD>.<i>`."""
META_BEGIN = "simreel.episode_begin"
META_EPISODE = "simreel.episode"
META_DISCARD = "simreel.episode_discard"
WORLD_FRAME = "world"


def step_ns_of(meta: RecordingMeta) -> int:
    """Nanoseconds of log time per env step: the control period (1 s when the recording lacks it)."""
    return int(round(1e9 / meta.control_freq)) if meta.control_freq else 1_000_000_000


def lock_file(fh: IO[bytes], *, exclusive: bool) -> bool:
    """Take an advisory lock without waiting; False if another open file holds it (True where unsupported).

    The writer holds an exclusive lock for its whole life, so a reader can tell a file that is still
    being written from one whose recording process died (the kernel drops the locks of a dead process).
    A shared lock is only a probe: it is released at once.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return True
    try:
        fcntl.flock(fh.fileno(), (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError:  # pragma: no cover - file systems without flock
        return True
    if not exclusive:
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
    return True


def being_written(path: str | Path) -> bool:
    """True while a `McapWriter` (in any process) has `path` open."""
    try:
        with open(path, "rb") as fh:
            return not lock_file(fh, exclusive=False)
    except OSError:
        return False
