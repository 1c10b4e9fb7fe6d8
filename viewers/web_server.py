"""The servers ``simreel view --serve`` runs: Rerun's web viewer (HTTP) and the gRPC server holding the session, in
one ``rerun --serve-web`` process listening on one address — this machine only (``127.0.0.1``) unless the user
names another (``--bind``). Rerun's Python servers (`rerun.serve_grpc`, `rerun.serve_web_viewer`) listen on every
interface and take no address, so the session is streamed into this process instead.

The process ends with the session (`WebServer.close`), and with this process if it is killed (Linux's
parent-death signal)."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from simreel.errors import UsageError, ViewError

__all__ = ["LOCALHOST", "WebServer", "start_web_server", "check_bind_address", "check_memory_limit", "reached_at",
           "listening", "web_viewer_url", "port_forward_line", "serve_file_command"]

LOCALHOST = "127.0.0.1"
"""Where ``--serve`` listens by default: a remote browser reaches it through ``ssh -L``."""

_START_TIMEOUT = 60.0
"""Seconds the server may take to listen on both ports (it starts in well under one)."""


def check_bind_address(address: str) -> str:
    """`address` if this machine can listen on it (an IPv4 or IPv6 address of one of its interfaces, or
    ``0.0.0.0`` / ``::`` for all of them), else `UsageError` naming it."""
    try:
        family = socket.AF_INET6 if ":" in address else socket.AF_INET
        socket.inet_pton(family, address)
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.bind((address, 0))
    except OSError as e:
        raise UsageError(f"--bind {address}: not an address this machine can listen on ({e.strerror or e}); give "
                         f"an IP address of one of its interfaces, e.g. {LOCALHOST} (this machine only, the "
                         "default) or 0.0.0.0 (every interface)") from None
    return address


_MEMORY_LIMIT = re.compile(r"^(\d+(\.\d+)?%|\d+(\.\d+)?\s*([KMGT]i?B|B))$", re.IGNORECASE)
"""What Rerun's ``--server-memory-limit`` takes: bytes with a unit (``2GB``, ``512MiB``) or a share of memory (``25%``)."""


def check_memory_limit(limit: str) -> str:
    """`limit` if Rerun's ``--server-memory-limit`` takes it, else `UsageError` saying what it takes."""
    if not _MEMORY_LIMIT.match(limit.strip()):
        raise UsageError(f"--server-memory-limit {limit}: give an amount with its unit, e.g. 2GB or 512MiB, or a share "
                         "of this machine's memory, e.g. 25%")
    return limit.strip().replace(" ", "")


def web_viewer_url(web_port: int, grpc_url: str, host: str = "localhost") -> str:
    """The web viewer's address with the gRPC server to open (``?url=rerun%2Bhttp://...``: a ``+`` left as it is
    would reach the viewer as a space) and the WebGL renderer: Rerun's default, WebGPU, fails in a browser that
    renders in software (a machine without a GPU), WebGL works there and everywhere else."""
    from urllib.parse import quote

    return f"http://{host}:{web_port}/?url={quote(grpc_url, safe=':/[]')}&renderer=webgl"


def port_forward_line(web_port: int, grpc_port: int) -> str:
    """How a browser on another machine reaches servers listening on this one's 127.0.0.1: both ports forwarded."""
    return (f"from another machine: ssh -L {web_port}:localhost:{web_port} -L {grpc_port}:localhost:{grpc_port} "
            "USER@THIS-HOST, then open the URL there")


def serve_file_command(viewer: str, rrd: str, *, web_port: int = 9090, grpc_port: int = 9876) -> str:
    """The shell command that serves a saved .rrd to a browser (this machine only), with `viewer` the Rerun
    executable as the shell spells it."""
    import shlex

    return (f"{viewer} --serve-web {shlex.quote(rrd)} --bind {LOCALHOST} --web-viewer-port {web_port} "
            f"--port {grpc_port} --renderer webgl")


def reached_at(address: str) -> str:
    """The host this machine reaches a server bound to `address` at, as a URL spells it."""
    host = {"0.0.0.0": LOCALHOST, "::": "::1"}.get(address, address)
    return f"[{host}]" if ":" in host else host


@dataclass
class WebServer:
    """A running ``rerun --serve-web`` process and where it listens."""

    process: subprocess.Popen
    bind: str
    web_port: int
    grpc_port: int
    log: IO[bytes] = field(repr=False)
    """What the server printed (its last line names why it stopped, if it did)."""

    @property
    def grpc_url(self) -> str:
        """The gRPC server's address, as the web viewer and ``rerun.RecordingStream.connect_grpc`` take it."""
        return f"rerun+http://{reached_at(self.bind)}:{self.grpc_port}/proxy"

    def close(self) -> None:
        """Stop the server (SIGTERM, then SIGKILL after 10 s) and forget its log."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.log.close()


def start_web_server(*, bind: str = LOCALHOST, web_port: int = 9090, grpc_port: int = 9876,
                     memory_limit: str | None = None) -> WebServer:
    """Start the servers on `bind` and wait until both ports answer; `ViewError` naming why when the process
    stops first (or does not listen within a minute). `memory_limit` (``2GB``, ``25%``; None: Rerun's default)
    bounds what the gRPC server keeps for viewers that connect later: past it, the oldest data is dropped."""
    log = tempfile.TemporaryFile()
    command = [_server_executable(), "--serve-web", "--bind", bind, "--port", str(grpc_port),
               "--web-viewer-port", str(web_port), "--renderer", "webgl"]
    if memory_limit is not None:
        command += ["--server-memory-limit", check_memory_limit(memory_limit)]
    process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                               preexec_fn=_end_with_parent)
    server = WebServer(process, bind, web_port, grpc_port, log)
    try:
        _wait_listening(server)
    except BaseException:
        server.close()
        raise
    return server


def _wait_listening(server: WebServer) -> None:
    deadline = time.monotonic() + _START_TIMEOUT
    host = reached_at(server.bind).strip("[]")
    while not all(listening(port, host) for port in (server.web_port, server.grpc_port)):
        if server.process.poll() is not None or time.monotonic() > deadline:
            raise ViewError(f"the Rerun web server did not start ({_last_line(server.log)}); use --save OUT.rrd "
                            "and open it elsewhere")
        time.sleep(0.05)


def listening(port: int, host: str = LOCALHOST) -> bool:
    """Whether something accepts connections on `port` of this machine at `host` (a viewer's or a server's)."""
    try:
        with socket.create_connection((host, port), timeout=1.0) as s:
            return s.getsockname() != s.getpeername()  # a free port in the ephemeral range can connect to itself
    except OSError:
        return False


def _last_line(log: IO[bytes]) -> str:
    log.seek(0)
    lines = [line.strip() for line in log.read().decode(errors="replace").splitlines() if line.strip()]
    return lines[-1] if lines else "it printed nothing"


def _server_executable() -> str:
    """The Rerun binary itself (the ``rerun`` script beside Python runs it as a child, which a signal to the script
    would leave running), else the viewer executable."""
    with contextlib.suppress(ImportError):
        import rerun_cli

        binary = Path(rerun_cli.__file__).parent / "rerun"
        if binary.is_file() and os.access(binary, os.X_OK):
            return str(binary)
    from simreel.viewers.session import viewer_executable

    found = viewer_executable()
    if found is None:
        raise ViewError("no Rerun executable found (it comes with rerun-sdk); use --save OUT.rrd")
    return found


def _end_with_parent() -> None:
    """In the server's process before it runs: SIGTERM when simreel's process ends, even by kill -9 (Linux)."""
    if sys.platform.startswith("linux"):
        import ctypes

        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    os.setpgrp()  # Ctrl-C in the terminal reaches simreel, which stops the server itself
