"""`ProcessWriter`: a recording's writer run in a child process, so that committing an episode (compression,
checksums, HDF5's object headers: ~4 ms an HDF5 episode) runs beside the env's own reset instead of before it.

The recorder keeps the writer's interface: `begin_episode` gives a sink, whose `append`, `commit` and `discard`
are sent to the child in order and return at once; each block is checked against the field table here first, so
a bad block still fails where it is appended. `settle` waits until the child has done everything sent so far and
raises the error the child met first, if any (the same error, e.g. the one-line `StorageError` of a full disk). A
recorder settles at the end of every reset and `close` settles too, so once `reset()` returns the episodes it ended
are committed, as with a writer in the same process.

The child holds the file's locks and writes where the format's writer says, as that writer would in the recorder's
own process. It ignores SIGINT and SIGTERM: the recorder handles them and tells it what to keep. If the recorder
dies (`kill -9`), the child does what it was sent before and then exits at once, as the recorder would have: the
running episodes are not committed and a staged `--overwrite` replaces nothing.

Run as `python -m simreel.formats.writer_process READ_FD WRITE_FD` by `ProcessWriter` only.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from simreel.episode import EpisodeMeta, RecordingMeta, StepBlock, episode_fields
from simreel.errors import RecordingFileError
from simreel.formats.durable import deferred_signals

__all__ = ["ProcessWriter"]

_START_SECONDS = 120
"""A child that has not opened the writer this long after it was started (~0.4 s on an idle machine) is ended:
`sys.executable` may not be a Python that runs simreel (an application that embeds Python)."""


class ProcessWriter:
    """The writer `open_writer(path, meta, **options)` would give, run in a child process; see the module docstring.

    Making one spawns the child (its imports take ~0.3 s), so the caller can build its metadata meanwhile; `open`
    then opens the writer there and raises what opening it raised (e.g. a refused target); `cancel` ends a child
    that will not be opened.
    """

    def __init__(self) -> None:
        to_child, to_child_writes = os.pipe()
        from_child_reads, from_child = os.pipe()
        self._child = subprocess.Popen(
            [sys.executable, "-m", "simreel.formats.writer_process", str(to_child), str(from_child)],
            pass_fds=(to_child, from_child), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
        )
        os.close(to_child)
        os.close(from_child)
        self._send_conn = Connection(to_child_writes, readable=False)
        self._recv_conn = Connection(from_child_reads, writable=False)
        self.path: Path | None = None
        self.fields: list[Any] = []
        self.reset_fields: list[Any] = []
        self.child_cpu_seconds = 0.0
        """CPU time the child spent writing, from the writer's opening to its close (its start-up, ~0.35 s of imports
        once, left out); known once `close` has returned. Benchmarks print it beside the recorder's own."""
        self._opened_cpu = 0.0
        self._target: Path | None = None
        """The file asked for (`path` is the one the writer opened)."""
        self._lost: RecordingFileError | None = None
        """Set once the child has gone away unasked: every later write raises it; cleanup (discard, close) is quiet."""
        self._closed = False

    def open(self, path: str | Path, meta: RecordingMeta, **options: Any) -> ProcessWriter:
        self.fields = episode_fields(meta)
        self.reset_fields = [f for f in self.fields if f.per_state]
        self._target = Path(path)
        try:
            self._send(("open", str(path), meta, options))
            opened, self._opened_cpu = self._reply(timeout=_START_SECONDS)
            self.path = Path(opened)
        except BaseException:
            self.cancel()
            raise
        return self

    def cancel(self) -> None:
        """End a child whose writer was never opened (or failed to open)."""
        self._closed = True
        self._end_child()

    def begin_episode(self, meta: EpisodeMeta, reset: StepBlock) -> _ProcessSink:
        arrays = reset.conform(self.reset_fields, episode=meta.index)
        self._send(("begin", meta, StepBlock(arrays, reset.rows)))
        return _ProcessSink(self, meta.index)

    def settle(self) -> None:
        """Wait until the child has done everything sent so far; raise the first error it met since the last settle."""
        self._send(("settle",))
        self._reply()

    def close(self) -> None:
        """Settle, close the writer in the child (a staged recording replaces the old one now) and wait for the child
        to exit. Raises the child's first error not yet raised, or the one closing met."""
        cpu = self._last("close")
        if cpu is not None:
            self.child_cpu_seconds = cpu - self._opened_cpu

    def abort(self) -> None:
        """Drop the whole recording (the format writer's `abort`) and end the child."""
        self._last("abort")

    def _last(self, op: str) -> Any:
        """Send the child its last message, `op` ("close" or "abort"), and wait for it to exit; its answer (None when
        the child was gone already, or had ended before)."""
        if self._closed:
            return None
        self._closed = True
        try:
            if self._lost is None:
                self._send((op,))
                return self._reply()
            return None
        finally:
            self._end_child()

    # ------------------------------------------------------------------ the pipe
    def _send(self, message: tuple[Any, ...]) -> None:
        """Send one message whole: a signal in the middle of one would leave the child reading half of it."""
        if self._lost is not None:
            raise self._lost
        try:
            with deferred_signals():
                self._send_conn.send(message)
        except OSError:
            raise self._gone() from None

    def _reply(self, timeout: float | None = None) -> Any:
        """The child's answer to the last message sent; `timeout`: seconds after which a child that has not answered
        is ended and taken for gone."""
        try:
            if timeout is not None and not self._recv_conn.poll(timeout):
                self._child.kill()
                raise self._gone(f"did not answer in {timeout:.0f} s")
            status, value = self._recv_conn.recv()
        except (EOFError, OSError):
            raise self._gone() from None
        if status == "error":
            raise _rebuilt(value)
        return value

    def _gone(self, how: str = "") -> RecordingFileError:
        try:
            code = self._child.wait(timeout=5)
        except subprocess.TimeoutExpired:
            code = None
        how = how or ("stopped answering" if code is None else f"ended (exit status {code})")
        if self.path is None:  # it never opened the writer
            return RecordingFileError(self._target, f"the writer process ({sys.executable} -m simreel.formats."
                                      f"writer_process) {how} before it opened the file; record with "
                                      "writer_process=False to write in this process")
        self._lost = RecordingFileError(self.path or "the recording", f"the writer process (pid {self._child.pid}) "
                                        f"{how}; the episodes committed before it did are in the file")
        return self._lost

    def _end_child(self) -> None:
        self._hang_up()
        try:
            self._child.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._child.kill()
            self._child.wait()

    def __enter__(self) -> ProcessWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        # A writer dropped without close (its recorder never closed): close the pipe so the child exits as after
        # a crash of the recorder, never waiting for more.
        if not getattr(self, "_closed", True):
            self._hang_up()

    def _hang_up(self) -> None:
        """Close both ends of the pipe (the child reads the end of its input and exits)."""
        self._send_conn.close()
        self._recv_conn.close()


class _ProcessSink:
    """A running episode in the child: what `EpisodeSink` does, sent."""

    def __init__(self, writer: ProcessWriter, index: int) -> None:
        self._writer = writer
        self._index = index

    def append(self, block: StepBlock) -> None:
        arrays = block.conform(self._writer.fields, episode=self._index)
        self._writer._send(("append", self._index, StepBlock(arrays, block.rows)))

    def commit(self, meta: EpisodeMeta) -> None:
        self._writer._send(("commit", self._index, meta))

    def discard(self) -> None:
        if self._writer._lost is None:  # a child that is gone keeps nothing of it anyway
            self._writer._send(("discard", self._index))


# ---------------------------------------------------------------------- errors across the pipe
def _portable(e: BaseException) -> tuple[str, str, tuple[Any, ...], dict[str, Any]]:
    """`e` as (module, class name, args, attributes): simreel's errors take other arguments than their message, so
    pickle could not rebuild them."""
    return type(e).__module__, type(e).__qualname__, e.args, dict(getattr(e, "__dict__", {}))


def _rebuilt(portable: tuple[str, str, tuple[Any, ...], dict[str, Any]]) -> BaseException:
    import importlib

    module, name, args, attributes = portable
    try:
        cls = getattr(importlib.import_module(module), name)
        e = cls.__new__(cls)
        BaseException.__init__(e, *args)
        e.__dict__.update(attributes)
        return e
    except Exception:  # noqa: BLE001 - a class this process cannot rebuild: its message still says what happened
        return RuntimeError(f"{module}.{name}: {args[0] if args else ''}")


# ---------------------------------------------------------------------- the child
class _Child:
    """Carries out what the recorder sends, in order; after an error, only what cleans up (discard, close, abort),
    until a settle has reported it."""

    def __init__(self, recv: Connection, send: Connection) -> None:
        self._recv, self._send = recv, send
        self._writer: Any = None
        self._sinks: dict[int, Any] = {}
        self._error: BaseException | None = None

    def run(self) -> None:
        while True:
            try:
                message = self._recv.recv()
            except (EOFError, OSError):  # the recorder is gone without closing: leave everything as a crash would
                os._exit(0)
            op, args = message[0], message[1:]
            getattr(self, f"_{op}")(*args)
            if op in ("close", "abort"):
                return

    def _reply(self, value: Any = None) -> None:
        error, self._error = self._error, None
        self._send.send(("error", _portable(error)) if error is not None else ("ok", value))

    def _guarded(self, work: Any, *args: Any) -> None:
        if self._error is not None:
            return
        try:
            work(*args)
        except Exception as e:  # noqa: BLE001 - every error goes back to the recorder, which raises it
            self._error = e

    def _open(self, path: str, meta: RecordingMeta, options: dict[str, Any]) -> None:
        from simreel.formats import open_writer

        def opened() -> None:
            self._writer = open_writer(path, meta, **options)

        self._guarded(opened)
        self._reply((str(self._writer.path), time.process_time()) if self._writer is not None else None)
        if self._writer is None:
            os._exit(0)

    def _begin(self, meta: EpisodeMeta, reset: StepBlock) -> None:
        def begun() -> None:
            self._sinks[meta.index] = self._writer.begin_episode(meta, reset)

        self._guarded(begun)

    def _append(self, index: int, block: StepBlock) -> None:
        sink = self._sinks.get(index)
        if sink is not None:
            self._guarded(sink.append, block)

    def _commit(self, index: int, meta: EpisodeMeta) -> None:
        sink = self._sinks.pop(index, None)
        if sink is not None:
            self._guarded(sink.commit, meta)

    def _discard(self, index: int) -> None:
        sink = self._sinks.pop(index, None)
        if sink is not None:
            try:
                sink.discard()
            except Exception as e:  # noqa: BLE001
                self._error = self._error or e

    def _settle(self) -> None:
        self._reply()

    def _close(self) -> None:
        try:
            self._writer.close()
        except Exception as e:  # noqa: BLE001
            self._error = self._error or e
        self._reply(time.process_time())

    def _abort(self) -> None:
        try:
            self._writer.abort()
        except Exception as e:  # noqa: BLE001
            self._error = self._error or e
        self._reply()


def _main(read_fd: int, write_fd: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _Child(Connection(read_fd, writable=False), Connection(write_fd, readable=False)).run()


if __name__ == "__main__":
    _main(int(sys.argv[1]), int(sys.argv[2]))
