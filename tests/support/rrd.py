"""Read a Rerun .rrd back with rerun-sdk's own reader (`rerun.chunk.RrdReader`), and what a gRPC server serves
with the `rerun` command's own client (`rerun download`); a `rerun` gRPC server to stand in for an open viewer."""

from __future__ import annotations

import contextlib
import dataclasses
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

__all__ = ["RrdContents", "read_rrd", "read_served", "running_grpc_server"]


@dataclasses.dataclass
class RrdContents:
    """What an .rrd holds: `data[entity][column]` → list of (step or None for static, value)."""

    data: dict[str, dict[str, list[tuple[int | None, Any]]]]
    blueprint_views: list[str]
    blueprint_entities: list[str]
    recording_ids: list[str]

    def at(self, entity: str, column: str, step: int | None) -> Any:
        for s, value in self.data[entity][column]:
            if s == step:
                return value
        raise KeyError(f"{entity} {column} has no row at step {step}")

    def steps(self, entity: str, column: str) -> list[int]:
        return [s for s, _ in self.data[entity][column] if s is not None]


def _columns(batch: Any) -> dict[str, list]:
    """A record batch as {column: python list}; time columns as int64 (nanoseconds for log_time/sim_time)."""
    import pyarrow as pa

    out = {}
    for name, column in zip(batch.schema.names, batch.columns, strict=True):
        if pa.types.is_temporal(column.type):
            column = column.cast(pa.int64())
        out[name] = column.to_pylist()
    return out


def _chunks(reader: Any, entry: Any = None) -> Any:
    """The chunks of one store: through the file's manifest, or by scanning a file written without one (what
    `rerun download` writes)."""
    import warnings

    try:
        return reader.store(store=entry).stream().to_chunks()
    except RuntimeError:  # "Legacy RRD without footer"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return reader.stream(store=entry).to_chunks()


def read_rrd(path: Path) -> RrdContents:
    import warnings

    import rerun as rr

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "RRD file has no footer": read by scanning, below
        reader = rr.chunk.RrdReader(path)
    data: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in _chunks(reader):
        if chunk.entity_path.startswith("/__properties"):
            continue
        rows = _columns(chunk.to_record_batch())
        steps = rows.get("step", [None] * chunk.num_rows)
        for column, values in rows.items():
            if column in ("step", "sim_time") or column.startswith("rerun."):
                continue
            data[chunk.entity_path][column].extend(zip(steps, values, strict=True))
    views, entities = [], []
    for entry in reader.blueprints():
        for chunk in _chunks(reader, entry):
            entities.append(chunk.entity_path)
            rows = _columns(chunk.to_record_batch())
            views += [v[0] if isinstance(v, list) else v for v in rows.get("ViewBlueprint:class_identifier", [])]
    return RrdContents({k: dict(v) for k, v in data.items()}, views, entities,
                       [e.recording_id for e in reader.recordings()])


def read_served(grpc_url: str, folder: Path, done: Callable[[RrdContents], bool], timeout: float = 120) -> RrdContents:
    """What the gRPC server at `grpc_url` serves, as `rerun download` receives it into `folder`: read again
    and again until `done(contents)` holds (a live server never ends its stream); AssertionError at `timeout`."""
    import contextlib
    import os
    import signal
    import subprocess
    import time

    from simreel.viewers.session import viewer_executable

    folder.mkdir(parents=True, exist_ok=True)
    log = folder.parent / f"{folder.name}.log"
    # its own process group: the `rerun` script runs the real binary as a child, and both must end
    with log.open("wb") as err:
        client = subprocess.Popen([viewer_executable(), "download", grpc_url, "-o", str(folder)],
                                  stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
    deadline = time.monotonic() + timeout
    last: RrdContents | str = "nothing downloaded"
    try:
        while time.monotonic() < deadline:
            time.sleep(1)
            for path in folder.glob("*.rrd"):
                try:
                    last = read_rrd(path)
                except Exception as e:  # noqa: BLE001 - a file still being written, read again
                    last = f"{type(e).__name__}: {e}"
                    continue
                if done(last):
                    return last
            if client.poll() is not None:
                raise AssertionError(f"rerun download ended with {client.returncode}: {log.read_text()[-2000:]}")
        raise AssertionError(f"{grpc_url}: not served in {timeout} s; last read: {last}")
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(client.pid, signal.SIGKILL)
        client.wait()


@contextlib.contextmanager
def running_grpc_server(port: int, log: Path, timeout: float = 60) -> Iterator[str]:
    """A real ``rerun --serve-grpc`` on `port` (what an open Rerun viewer listens with, minus the window), its
    output in `log`; yields its URL once it accepts connections, and at the end kills it and waits until nothing
    listens on `port` any more (its process group can outlive the process waited for by a moment)."""
    import os
    import signal
    import subprocess
    import time

    from simreel.viewers.session import viewer_executable
    from simreel.viewers.web_server import listening as _listening

    with log.open("wb") as out:
        server = subprocess.Popen([viewer_executable(), "--serve-grpc", "--port", str(port)],
                                  stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + timeout
        while not _listening(port):
            if server.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"rerun --serve-grpc never listened: {log.read_text()[-2000:]}")
            time.sleep(0.2)
        yield f"rerun+http://127.0.0.1:{port}/proxy"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(server.pid, signal.SIGKILL)
        server.wait()
        deadline = time.monotonic() + timeout
        while _listening(port) and time.monotonic() < deadline:
            time.sleep(0.05)
