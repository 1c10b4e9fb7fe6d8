"""Running simreel as a user's shell would, for the tests whose behaviour is a process's: exit status, the
lines it prints, signals, ports it serves."""

from __future__ import annotations

import os
import socket
import sys
from collections.abc import Mapping

__all__ = ["DISPLAY_VARS", "free_port", "simreel_command", "without_display"]

DISPLAY_VARS = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")
"""The variables through which a process finds an X11 or Wayland display."""


def simreel_command(*args: str) -> list[str]:
    """``python -m simreel ARGS`` with this venv's Python."""
    return [sys.executable, "-m", "simreel", *args]


def without_display(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """`env` (default os.environ) with no display: what a headless machine or an ssh session without -X has."""
    return {k: v for k, v in (os.environ if env is None else env).items() if k not in DISPLAY_VARS}


def free_port() -> int:
    """A TCP port nothing listens on now (the OS picks it), for a server a test starts; never a fixed one."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
