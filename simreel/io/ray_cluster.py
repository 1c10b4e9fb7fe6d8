"""Joining or starting the Ray cluster a command runs its episodes on (`simreel replay --ray`, `simreel export
--ray`): `import_ray` (a one-line error where Ray is not installed), `connect` (``ray.init`` for "local", "auto" or
an address, a one-line error where there is no cluster, simreel's own signal handlers kept) and `worker_count` (at
most one worker a CPU of the cluster).

Ray is an optional dependency (``pip install 'simreel[ray]'``); it is imported only when a command asks for it."""

from __future__ import annotations

import contextlib
import logging
import signal
import socket
import threading
from collections.abc import Iterator
from typing import Any

from simreel.errors import UsageError

__all__ = ["import_ray", "connect", "worker_count"]

_OBJECT_STORE_BYTES = 256 * 1024**2
"""Object store of a cluster started here: enough for shipped episodes, small beside the envs."""


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise UsageError("--ray needs Ray: pip install 'simreel[ray]' (in simreel's repository: "
                         ".venv/bin/pip install -e '.[ray]')") from None
    return ray


def connect(ray: Any, address: str) -> None:
    """Join or start the cluster; `UsageError` naming the address when there is none. simreel's own SIGINT and
    SIGTERM handlers stay in place (`ray.init` installs its own, which would end a run with Ray's dumps and exit
    15 instead of the report's resume hint)."""
    quiet = {"logging_level": logging.ERROR, "log_to_driver": False, "include_dashboard": False}
    if address != "local":
        _check_reachable(address)
    with _signal_handlers_kept():
        try:
            if address == "local":
                # "local": a private instance, also where `ray start` runs a cluster (plain init would join it)
                ray.init(address="local", object_store_memory=_OBJECT_STORE_BYTES, **quiet)
            else:
                ray.init(address=address, **quiet)
        except (ConnectionError, RuntimeError, ValueError) as e:
            if address == "local":
                raise UsageError(f"--ray: cannot start Ray on this machine ({type(e).__name__}: {e}); join a "
                                 "running cluster instead (--ray auto, or its address)") from None
            raise UsageError(f"--ray {address}: no Ray cluster to join there ({type(e).__name__}: {e}); start one "
                             "(ray start --head) or give its address (host:6379, ray://host:10001)") from None


_CONNECT_SECONDS = 5.0
"""How long `_check_reachable` waits for a cluster's port to answer (Ray itself would retry for ever)."""


def _check_reachable(address: str) -> None:
    """`UsageError` when nothing listens at a ``host:port`` or ``ray://host:port`` address: `ray.init` retries such
    an address for ever. "auto" is Ray's to find (it fails at once when this machine belongs to no cluster)."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if address == "auto" or not sep or not port.isdigit():
        return
    host = host.strip("[]")  # an IPv6 address in brackets
    try:
        socket.create_connection((host, int(port)), timeout=_CONNECT_SECONDS).close()
    except OSError as e:
        why = "no answer" if isinstance(e, TimeoutError) else (e.strerror or str(e))
        raise UsageError(f"--ray {address}: no Ray cluster answers there ({why}); start one (ray start --head) or "
                         "give its address (host:6379, ray://host:10001)") from None


@contextlib.contextmanager
def _signal_handlers_kept() -> Iterator[None]:
    """Put simreel's SIGINT and SIGTERM handlers back after the block (`ray.init` replaces them: its SIGTERM one
    exits 15, and its core worker prints a stack dump), so a stopped run ends as a local one does. Only the main
    thread sets handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    kept = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in kept.items():
            if handler is not None:
                signal.signal(s, handler)  # also takes the signal back from Ray's C++ handler


def worker_count(ray: Any, workers: int, *, did: str) -> tuple[int, list[str]]:
    """How many workers to start for `workers` (each takes one CPU) and the note that says so (`did`: what they did,
    e.g. "replayed") when the cluster has fewer CPUs: Ray would wait for ever to place the others. `UsageError` for a cluster without CPUs."""
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if cpus < 1:
        raise UsageError("--ray: the Ray cluster has no CPU for a worker (each takes one); add a node with CPUs")
    if workers <= cpus:
        return workers, []
    return cpus, [f"--workers {workers}: the Ray cluster has {cpus} CPU(s), one per worker, so {cpus} worker(s) "
                  f"{did}"]


