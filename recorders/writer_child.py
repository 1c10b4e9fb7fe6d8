"""The writer process's side of `simreel.recorders.writer_process.ProcessWriter`: `main` carries out what the
recorder sends, in order, with the format's own writer (`_Child`), and errors travel back across the pipe as
(module, class, args, attributes) (`portable_error`, rebuilt by the recorder with `rebuilt_error`).

Run by `ProcessWriter` only (its `_BOOTSTRAP` program).
"""

from __future__ import annotations

import os
import pickle
import time
from multiprocessing.connection import Connection
from typing import Any

from simreel.model.blocks import StepBlock
from simreel.model.meta import EpisodeMeta, RecordingMeta

__all__ = ["main", "portable_error", "rebuilt_error"]

_PARENT_CHECK_SECONDS = 1.0
"""How often an idle child checks that its recorder still runs (a forked process may hold the pipe open)."""


def portable_error(e: BaseException) -> tuple[str, str, tuple[Any, ...], dict[str, Any]]:
    """`e` as (module, class name, args, attributes): simreel's errors take other arguments than their message, so
    pickle could not rebuild them; an OSError's args carry its errno, message and file names. What cannot be pickled
    travels as a RuntimeError with the error's text."""
    args = e.args
    if isinstance(e, OSError) and e.errno is not None:
        args = (e.errno, e.strerror, e.filename, None, e.filename2)
    portable = (type(e).__module__, type(e).__qualname__, args, dict(getattr(e, "__dict__", {})))
    try:
        pickle.dumps(portable)
    except Exception:  # noqa: BLE001 - anything may fail to pickle
        return "builtins", "RuntimeError", (f"{type(e).__name__}: {e}",), {}
    return portable


def rebuilt_error(portable: tuple[str, str, tuple[Any, ...], dict[str, Any]]) -> BaseException:
    import importlib

    module, name, args, attributes = portable
    try:
        cls = getattr(importlib.import_module(module), name)
        if issubclass(cls, OSError):
            return cls(*args)
        e = cls.__new__(cls)
        BaseException.__init__(e, *args)
        e.__dict__.update(attributes)
        return e
    except Exception:  # noqa: BLE001 - a class this process cannot rebuild: its message still says what happened
        return RuntimeError(f"{module}.{name}: {args[0] if args else ''}")


class _Child:
    """Carries out what the recorder sends, in order. After an error nothing more is written (the writer is stopped,
    as it would be in the recorder's process); only what cleans up (discard, close, abort) still runs."""

    def __init__(self, recv: Connection, send: Connection, parent: int) -> None:
        self._recv, self._send = recv, send
        self._parent = parent
        self._writer: Any = None
        self._sinks: dict[int, Any] = {}
        self._error: BaseException | None = None
        """The first error met (every answer carries it)."""
        self._stopped = False
        self._committed: list[int] = []
        """Episodes committed since the last answer."""
        self._sources: dict[int, Any] = {}
        """The row sources the recorder sent, by number (`ProcessWriter._source_number`)."""

    def run(self) -> None:
        self._answer_raw(("ready", None, []))
        while True:
            message = self._next()
            op, args = message[0], message[1:]
            getattr(self, f"_{op}")(*args)
            if op in ("close", "abort"):
                return

    def _next(self) -> tuple[Any, ...]:
        """The next message; at the end of the input (the recorder is gone without closing), exit at once, leaving
        everything as a crash of the recorder would."""
        try:
            while not self._recv.poll(_PARENT_CHECK_SECONDS):
                if os.getppid() != self._parent:  # the recorder died; a process it forked holds the pipe open
                    os._exit(0)
            return self._recv.recv()
        except (EOFError, OSError):
            os._exit(0)

    def _answer(self, value: Any = None) -> None:
        """Answer with `value`, the episodes committed since the last answer, and the error that stopped the writer
        (in every answer from then on: the recorder may have been interrupted before it read the first)."""
        if self._error is not None:
            self._say("error", portable_error(self._error))
        else:
            self._say("ok", value)

    def _say(self, status: str, value: Any) -> None:
        """Send (status, value, the episodes committed since the last message)."""
        committed, self._committed = self._committed, []
        self._answer_raw((status, value, committed))

    def _answer_raw(self, answer: tuple[str, Any, list[int]]) -> None:
        try:
            self._send.send(answer)
        except OSError:  # the recorder is gone
            os._exit(0)

    def _guarded(self, work: Any, *args: Any) -> bool:
        """Run a write unless the writer has stopped; an error stops it, and is told at once (the recorder reads it
        before its next write) and again in every answer."""
        if self._stopped:
            return False
        try:
            work(*args)
            return True
        except Exception as e:  # noqa: BLE001 - every error goes back to the recorder, which raises it
            self._error, self._stopped = e, True
            self._say("failed", portable_error(e))  # now: the recorder raises it at its next write
            return False

    def _cleanup(self, work: Any) -> None:
        try:
            work()
        except Exception as e:  # noqa: BLE001
            self._error = self._error or e

    def _open(self, path: str, meta: RecordingMeta, options: dict[str, Any]) -> None:
        from simreel.formats import open_writer

        def opened() -> None:
            self._writer = open_writer(path, meta, **options)

        self._guarded(opened)
        self._answer((str(self._writer.path), time.process_time()) if self._writer is not None else None)
        if self._writer is None:
            os._exit(0)

    def _begin(self, meta: EpisodeMeta, parts: tuple[Any, ...]) -> None:
        def begun() -> None:
            self._sinks[meta.index] = self._writer.begin_episode(meta, self._block(parts))

        self._guarded(begun)

    def _scene(self, geometry: Any) -> None:
        self._guarded(self._writer.write_scene, geometry)

    def _learn(self, number: int, source: Any, forget: int | None) -> None:
        if forget is not None:
            del self._sources[forget]
        self._sources[number] = source

    def _block(self, parts: tuple[dict[str, Any], int, tuple[Any, ...]]) -> StepBlock:
        """The block `ProcessWriter.block_parts` sent."""
        arrays, rows, captured = parts
        return StepBlock(arrays, rows, tuple((self._sources[number], held, env) for number, held, env in captured))

    def _append(self, index: int, parts: tuple[Any, ...]) -> None:
        sink = self._sinks.get(index)
        if sink is not None:
            self._guarded(sink.append, self._block(parts))  # the format's sink converts what the recorder captured

    def _finish(self, index: int, parts: tuple[Any, ...] | None, meta: EpisodeMeta) -> None:
        if parts is not None:
            self._append(index, parts)
        sink = self._sinks.pop(index, None)
        if sink is not None and self._guarded(sink.commit, meta):
            self._committed.append(index)

    def _discard(self, index: int) -> None:
        sink = self._sinks.pop(index, None)
        if sink is not None:
            self._cleanup(sink.discard)

    def _settle(self) -> None:
        self._answer()

    def _close(self, replace: bool) -> None:
        self._cleanup(lambda: self._writer.close(replace=replace))
        self._answer(time.process_time())

    def _abort(self) -> None:
        if self._writer is not None:
            self._cleanup(self._writer.abort)
        self._answer()


def main(read_fd: int, write_fd: int, parent: int) -> None:
    """The child's life (SIGINT and SIGTERM are ignored from its first line on, `_BOOTSTRAP`)."""
    _Child(Connection(read_fd, writable=False), Connection(write_fd, readable=False), parent).run()
