"""Running simreel as a user's shell would, for the tests whose behaviour is a process's: exit status, the
lines it prints, signals, ports it serves."""

from __future__ import annotations

import os
import selectors
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from contextlib import ExitStack, contextmanager

__all__ = ["DISPLAY_VARS", "answering_display", "free_port", "free_ports", "read_line", "simreel_command", "stop_ray_node",
           "without_display"]

DISPLAY_VARS = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")
"""The variables through which a process finds an X11 or Wayland display."""


def simreel_command(*args: str) -> list[str]:
    """``python -m simreel ARGS`` with this venv's Python."""
    return [sys.executable, "-m", "simreel", *args]


def without_display(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """`env` (default os.environ) with no display: what a headless machine or an ssh session without -X has."""
    return {k: v for k, v in (os.environ if env is None else env).items() if k not in DISPLAY_VARS}


@contextmanager
def answering_display() -> Iterator[dict[str, str]]:
    """An environment whose DISPLAY answers simreel's probe (a TCP listener where an X server of that display number
    would listen; it draws nothing, and hangs up on whoever connects, so an X client fails at once as on a display
    that refused it): for tests of `--spawn` when a viewer already listens on the port, where Rerun starts none."""
    import threading

    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.bind(("127.0.0.1", 0))
    listener.listen()

    def hang_up() -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:  # the listener was closed
                return
            connection.close()

    threading.Thread(target=hang_up, daemon=True).start()
    try:
        yield {**without_display(), "DISPLAY": f"127.0.0.1:{listener.getsockname()[1] - 6000}"}
    finally:
        listener.shutdown(socket.SHUT_RDWR)
        listener.close()


def free_port() -> int:
    """A TCP port nothing listens on now (the OS picks it), for a server a test starts; never a fixed one."""
    return free_ports(1)[0]


def free_ports(count: int) -> list[int]:
    """`count` different TCP ports nothing listens on now: each held bound until all are picked (one picked after
    another was let go may be the same port)."""
    with ExitStack() as held:
        sockets = [held.enter_context(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) for _ in range(count)]
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]


def read_line(process: subprocess.Popen[str], timeout: float) -> str:
    """The next line `process` writes to its stdout (a text pipe), without its newline; AssertionError if none
    comes within `timeout` seconds or the process ends first (its stderr then says why)."""
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as selector:
        selector.register(process.stdout, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if selector.select(timeout=0.5):
                line = process.stdout.readline()
                if line:
                    return line.rstrip("\n")
            if process.poll() is not None:
                raise AssertionError(f"exited with {process.returncode}: {process.stderr.read()[-3000:]}")
    raise AssertionError(f"no line on stdout in {timeout} s")


def stop_ray_node(node: subprocess.Popen, timeout: float = 60) -> None:
    """Stop a `ray start --block` node started in a session of its own: SIGTERM to `ray start` alone, which stops its
    node's processes and exits within seconds (SIGTERM to the whole group took 30 s: the raylet and the GCS, stopped
    under it, leave it waiting), then SIGKILL to whatever of the group is left."""
    node.terminate()
    try:
        node.wait(timeout=timeout)
    finally:
        try:
            os.killpg(node.pid, signal.SIGKILL)
        except ProcessLookupError:  # nothing left
            pass


def stop_child(child: subprocess.Popen[str], signum: int, timeout: float = 60) -> tuple[str, str]:
    """Send `signum`, wait for `child` to end and return (stdout, stderr) left unread, with what `read_line` left
    in the pipe's buffer (`communicate` reads past that buffer and loses it)."""
    child.send_signal(signum)
    child.wait(timeout=timeout)
    return child.stdout.read(), child.stderr.read()


def reap(child: subprocess.Popen[str]) -> None:
    """Kill `child` if it still runs (a test that failed while it served)."""
    if child.poll() is None:
        child.kill()
        child.communicate()
