"""`ProcessWriter`: a recording's writer run in a child process, so that committing an episode (compression,
checksums, HDF5's object headers: ~4 ms an HDF5 episode) runs beside the env's own reset instead of before it.

The recorder keeps the writer's interface: `begin_episode` gives a sink, whose `append`, `commit`, `finish` and
`discard` are sent to the child in order and return at once (`finish`, an episode's last block and its commit, as
one message); each block is checked against the field table here first, so a bad block still fails where it is
appended, but for the fields a block may bring as the recorder captured them (`StepBlock.captured`, one env's): the
child converts those (~0.4 ms a 50-step PickCube-v1 block, off the recorder's time; the format's sink does it) and
checks them before it writes them. Their row sources travel once each, then by number
(`ProcessWriter._source_number`). A block whose captures or sources do not pickle is converted here. `settle` waits
until the child has done everything sent (up to the last `checkpoint`) and raises the error the child met first, if
any (the same error, e.g. the one-line `StorageError` of a full disk); `committed` lists the episodes the child has
reported committed. A recorder sends the episodes a reset ends, asks for a `checkpoint`, resets the env and settles
at the end of the reset (the child's answer is waiting by then, not a round trip away); `close` settles too. So once
`reset()` returns the episodes it ended are committed, as with a writer in the same process. An error stops the
writer for good, as it stops a writer in the recorder's process: the child writes nothing more and tells it at once;
the next write here (or settle, or close) raises it, and every later write raises it again. (An error that begins the episode a reset starts, sent after the reset's checkpoint, is raised
by the next reset, or by a step that fills a block.)

The child holds the file's locks and writes where the format's writer says, as that writer would in the recorder's
own process. It runs in a session of its own and ignores SIGINT and SIGTERM: the recorder handles them and tells it
what to keep. If the recorder
dies (`kill -9`), the child does what it was sent before and then exits at once, as the recorder would have: the
running episodes are not committed and a staged `--overwrite` replaces nothing.

The child's side: `simreel.recorders.writer_child`.
"""

from __future__ import annotations

import fcntl
import os
import pickle
import select
import subprocess
import sys
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeWriter
from simreel.io.durable import deferred_signals
from simreel.model.blocks import StepBlock
from simreel.model.fields import episode_fields
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.recorders.writer_child import rebuilt_error

__all__ = ["ProcessWriter"]

_START_SECONDS = 120
"""A child that has not said it is ready this long after it was started (~0.4 s on an idle machine) is ended:
`sys.executable` may not be a Python that runs simreel (an application that embeds Python)."""
_STOP_SECONDS = 30
"""How long a child that does not answer is waited for once the recorder has been asked to stop (Ctrl-C, SIGTERM)."""
_MAX_SOURCES = 64
"""Row sources the child holds at most (`ProcessWriter._source_number`); at least as many as a block has (4)."""


class ProcessWriter:
    """The writer `open_writer(path, meta, **options)` would give, run in a child process; see the module docstring.
    It is an `EpisodeWriter` (registered as one: the format's own writer, in the child, does the writing, so nothing
    of the base class's is inherited) that converts captured rows itself (`converts_captures`).

    Making one spawns the child (its imports take ~0.3 s), so the caller can build its metadata meanwhile; `open`
    then opens the writer there and raises what opening it raised (e.g. a refused target); `cancel` ends a child
    that will not be opened.
    """

    converts_captures = True

    def __init__(self, path: str | Path) -> None:
        self._target = Path(path)
        """The file asked for (`path` is the one the writer opened)."""
        self.path: Path | None = None
        to_child, to_child_writes = _pipe()
        from_child_reads, from_child = _pipe()
        try:
            self._child = subprocess.Popen(
                [sys.executable, *_interpreter_flags(), "-c", _BOOTSTRAP, _simreel_root(),
                 str(to_child), str(from_child), str(os.getpid())],
                pass_fds=(to_child, from_child), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                start_new_session=True,  # a terminal's Ctrl-C reaches the recorder only, which tells the child
            )
        except (OSError, ValueError, TypeError) as e:  # TypeError: sys.executable is None
            for fd in (to_child_writes, from_child_reads):
                os.close(fd)
            raise self._not_started(f"could not start: {e}") from None
        finally:
            os.close(to_child)
            os.close(from_child)
        self._send_conn = Connection(to_child_writes, readable=False)
        self._recv_conn = Connection(from_child_reads, writable=False)
        self._news = select.poll()
        """Whether the child has said something (`_news_waiting`): one poll object for the writer's life, where
        `Connection.poll` builds a selector at every call (~8 µs; a recorder's reset asks three times)."""
        self._news.register(from_child_reads, select.POLLIN)
        self.fields: list[Any] = []
        self.reset_fields: list[Any] = []
        self.committed: list[EpisodeMeta] = []
        """The episodes the child has committed, in the order it committed them (known at each settle and close)."""
        self._committing: dict[int, EpisodeMeta] = {}
        """Episodes sent to be committed, by index, until the child reports them committed."""
        self._owed = 0
        """Answers the child owes (a Ctrl-C can interrupt the wait for one: it is read before the next)."""
        self._checkpoint_asked = False
        """Whether a `checkpoint` was asked for since the last `settle` (which then waits for its answer)."""
        self.child_cpu_seconds = 0.0
        """CPU time the child spent writing, from the writer's opening to its close (its start-up, ~0.35 s of imports
        once, left out); known once `close` has returned. Benchmarks print it beside the recorder's own."""
        self._opened_cpu = 0.0
        self._failed: BaseException | None = None
        """The error that stopped the writer (the child's, or the child gone unasked): every later write raises it;
        cleanup (discard, close) raises it only if it was never raised (a Ctrl-C may have cut in first)."""
        self._failure_raised = False
        self._closed = False
        self._sources: dict[Any, int] = {}
        """The row sources the child knows, and their numbers (`_source_number`), the least recently used first."""
        self._source_count = 0

    def open(self, meta: RecordingMeta, **options: Any) -> ProcessWriter:
        self.fields = episode_fields(meta)
        self.reset_fields = [f for f in self.fields if f.per_state]
        try:
            self._wait_ready()
            opened, self._opened_cpu = self._request(("open", str(self._target), meta, options))
            self.path = Path(opened)
        except BaseException:
            if self._owed and self._failed is None:  # interrupted while the child opens: it must drop what it made
                self._last("abort", quiet=True)  # which ends the child too
            else:
                self.cancel()
            raise
        return self

    def cancel(self) -> None:
        """End a child whose writer was never opened (or failed to open)."""
        self._closed = True
        self._end_child()

    def block_parts(self, block: StepBlock, episode: int,
                    fields: list[Any] | None = None) -> tuple[dict[str, Any], int, tuple[Any, ...]]:
        """`block` checked against the field table (`fields`: those of a reset row), as the child rebuilds it
        (`simreel.recorders.writer_child._Child._block`): its arrays, rows, and captures with their row sources by number (`_source_number`)."""
        arrays = block.conform(self.fields if fields is None else fields, episode=episode)
        return arrays, block.rows, tuple((self._source_number(s), held, env) for s, held, env in block.captured)

    def _source_number(self, source: Any) -> int:
        """The number the child knows row source `source` by, sent to it first if it does not know it yet. A source
        travels once rather than with every block: pickling one (its index array, its dtypes) costs ~80 µs an
        episode right after a step. The child holds the `_MAX_SOURCES` used last (each scene the env rebuilds has its
        own state source); a block's sources are used last of all when its own are numbered, so none is forgotten
        before the block arrives."""
        number = self._sources.pop(source, None)
        if number is None:
            number, forget = self._source_count, None
            if len(self._sources) >= _MAX_SOURCES:
                forget = self._sources.pop(next(iter(self._sources)))
            self._send(("learn", number, source, forget))
            self._source_count += 1
        self._sources[source] = number
        return number

    def begin_episode(self, meta: EpisodeMeta, reset: StepBlock) -> _ProcessSink:
        self._send(("begin", meta, self.block_parts(reset, meta.index, self.reset_fields)))
        return _ProcessSink(self, meta.index)

    def write_scene(self, geometry: Any) -> None:
        """The format writer's `write_scene`, in the child (geometry is plain data: it pickles)."""
        self._send(("scene", geometry))

    def checkpoint(self) -> None:
        """Ask the child to answer once it has done everything sent so far, and return at once: the next `settle`
        waits for that answer, which the child sends while the caller works on (the recorder asks once it has sent
        the episodes a reset ends, then resets the env, then settles)."""
        self._send(("settle",), answered=True)
        self._checkpoint_asked = True

    def settle(self) -> None:
        """Wait until the child has done everything sent up to the last `checkpoint` (when none was asked for since
        the last settle, everything sent so far); raise the error it met, if any."""
        if not self._checkpoint_asked:
            self.checkpoint()
        self._checkpoint_asked = False
        self._await_answers()

    def close(self, *, replace: bool = True) -> None:
        """Settle, close the writer in the child (a staged recording replaces the old one now, unless not `replace`)
        and wait for the child to exit. Raises the child's error not yet raised, or the one closing met."""
        cpu = self._last("close", replace)
        if cpu is not None:
            self.child_cpu_seconds = cpu - self._opened_cpu

    def abort(self) -> None:
        """Drop the whole recording (the format writer's `abort`) and end the child."""
        self._last("abort")

    def _last(self, op: str, *args: Any, quiet: bool = False) -> Any:
        """Send the child its last message, `op` ("close" or "abort") with `args`, and wait for it to exit; its answer
        (None when the child was gone already, or had ended before). `quiet`: raise nothing (cleaning up after
        another error)."""
        if self._closed:
            return None
        self._closed = True
        with deferred_signals() as held:  # like a writer's own close: a Ctrl-C now is handled once the file is finished
            try:
                if not isinstance(self._failed, _Gone):
                    return self._request((op, *args), after_failure=True, held=held)
                return None
            except BaseException:
                if not quiet:
                    raise
                return None
            finally:
                self._end_child()

    # ------------------------------------------------------------------ the pipe
    def _send(self, message: tuple[Any, ...], after_failure: bool = False, answered: bool = False) -> None:
        """Send one message whole (a signal in the middle of one would leave the child reading half of it); for a
        message the child answers (`answered`), count the answer owed before any signal is let through."""
        try:
            with deferred_signals():  # from the child's news to the send: a signal is handled once both are done
                if not after_failure:
                    while self._failed is None and self._news_waiting():  # the child's news: an error it met
                        self._read()
                if self._failed is None or after_failure:
                    self._send_conn.send(message)
                    self._owed += answered
                    return
        except OSError:
            raise self._gone() from None
        self._failure_raised = True
        raise self._failed

    def _news_waiting(self, seconds: float = 0) -> bool:
        """Whether the child has said something (or hung up), waiting up to `seconds` for it."""
        return bool(self._news.poll(seconds * 1000))

    def _request(self, message: tuple[Any, ...], after_failure: bool = False, held: list[int] | None = None) -> Any:
        """Send `message` and return the child's answer to it, after reading the answers owed to earlier requests
        (a Ctrl-C may have cut the wait for one); raises the writer's error if an answer carried one. `held`: the
        signals the caller holds (`_receive`)."""
        self._send(message, after_failure, answered=True)
        return self._await_answers(after_failure, held)

    def _await_answers(self, after_failure: bool = False, held: list[int] | None = None) -> Any:
        """Read every answer owed and return the last one's value; raise the writer's error if an answer carried
        one (`_request`)."""
        answer = None
        while self._owed:
            answer = self._receive(held)
        if self._failed is not None and (not after_failure or not self._failure_raised):
            self._failure_raised = True
            raise self._failed
        return answer

    def _receive(self, held: list[int] | None = None) -> Any:
        """Wait for the next answer, or the news of an error the child met (a signal may cut the wait), then read it
        and note what it says with signals held, so an answer is never half read or read and forgotten. Returns its
        value (None for an error).

        A caller that holds signals passes the list of those held (`deferred_signals`): once one is there, the child
        gets `_STOP_SECONDS` more to answer, then is killed (a stopped or stuck child must not make Ctrl-C and
        SIGTERM useless); the file is then as a kill -9 of the child leaves it."""
        try:
            asked_to_stop = None
            while not self._news_waiting(1.0):
                if held:
                    asked_to_stop = asked_to_stop or time.monotonic()
                    if time.monotonic() - asked_to_stop > _STOP_SECONDS:
                        self._child.kill()
        except OSError:
            raise self._gone() from None
        return self._read()

    def _read(self) -> Any:
        """Read the message waiting (`_receive`) and note what it says, with signals held."""
        try:
            with deferred_signals():
                status, answer, committed = self._recv_conn.recv()
                self._owed -= status != "failed"  # "failed" is the child's own news, not an answer (`simreel.recorders.writer_child._Child._guarded`)
                self.committed += [self._committing.pop(i) for i in committed]
                if status != "ok" and self._failed is None:
                    self._failed = rebuilt_error(answer)
        except (EOFError, OSError):
            raise self._gone() from None
        return answer if status == "ok" else None

    def _wait_ready(self) -> None:
        """Wait for the child's first word, said once it runs (a program that is not our child never says it)."""
        try:
            if not self._recv_conn.poll(_START_SECONDS):
                self._child.kill()
                raise self._not_started(f"did not answer in {_START_SECONDS:.0f} s")
            self._recv_conn.recv()
        except (EOFError, OSError):
            raise self._not_started(f"ended (exit status {self._exit_status()})") from None

    def _not_started(self, how: str) -> RecordingFileError:
        return RecordingFileError(self._target, f"the writer process ({sys.executable}) {how} before it opened the "
                                  "file; record with writer_process=False to write in this process")

    def _gone(self) -> RecordingFileError:
        code = self._exit_status()
        how = "stopped answering" if code is None else f"ended (exit status {code})"
        self._failed = _Gone(self.path or self._target, f"the writer process (pid {self._child.pid}) {how}; the "
                             "episodes committed before it did are in the file")
        return self._failed

    def _exit_status(self) -> int | None:
        try:
            return self._child.wait(timeout=5)
        except subprocess.TimeoutExpired:
            return None

    def _end_child(self) -> None:
        self._hang_up()
        try:
            self._child.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._child.kill()
            self._child.wait()

    def _hang_up(self) -> None:
        """Close both ends of the pipe (the child reads the end of its input and exits)."""
        self._send_conn.close()
        self._recv_conn.close()

    def __del__(self) -> None:
        # A writer dropped without close (its recorder never closed): close the pipe so the child exits as after
        # a crash of the recorder, never waiting for more.
        if not getattr(self, "_closed", True):
            self._hang_up()


EpisodeWriter.register(ProcessWriter)


class _Gone(RecordingFileError):
    """The writer process ended (or stopped answering) without being asked to."""


class _ProcessSink:
    """A running episode in the child: what `EpisodeSink` does, sent."""

    def __init__(self, writer: ProcessWriter, index: int) -> None:
        self._writer = writer
        self._index = index

    def append(self, block: StepBlock) -> None:
        self._send("append", block)

    def commit(self, meta: EpisodeMeta) -> None:
        self.finish(meta)

    def finish(self, meta: EpisodeMeta, last: StepBlock | None = None) -> None:
        """`EpisodeSink.finish`, as one message: the episode's last block and its commit."""
        self._send("finish", last, meta, committing=meta)

    def _send(self, op: str, block: StepBlock | None, *args: Any, committing: EpisodeMeta | None = None) -> None:
        """Send `op` for this episode with `block` (checked against the field table here) and `args`; `committing`:
        the episode this commits, noted as sent before the send (a Ctrl-C held during it is raised right after it).
        A block whose captures, or their row sources, do not pickle is converted here and sent as arrays."""
        try:
            parts = None if block is None else self._writer.block_parts(block, self._index)
            if committing is not None:
                self._writer._committing[committing.index] = committing
            self._writer._send((op, self._index, parts, *args))
        except (pickle.PicklingError, TypeError, AttributeError):  # nothing of this block was sent
            if block is None or not block.captured:
                raise
            self._send(op, block.converted(), *args, committing=committing)

    def discard(self) -> None:
        if not isinstance(self._writer._failed, _Gone):  # a child that is gone keeps nothing of it anyway
            self._writer._send(("discard", self._index), after_failure=True)


_BOOTSTRAP = (
    "import signal, sys\n"
    "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
    "if sys.path and sys.path[0] == '':\n"
    "    del sys.path[0]\n"
    "from importlib.machinery import PathFinder\n"
    "from importlib.util import module_from_spec\n"
    "root, read_fd, write_fd, parent = sys.argv[1:]\n"
    "spec = PathFinder.find_spec('simreel', [root])\n"
    "sys.modules['simreel'] = module_from_spec(spec)\n"
    "spec.loader.exec_module(sys.modules['simreel'])\n"
    "from simreel.recorders.writer_child import main\n"
    "main(int(read_fd), int(write_fd), int(parent))\n"
)
"""The child's program: it ignores SIGINT and SIGTERM (the recorder handles them and tells it what to keep) and runs
the simreel this process runs, loaded from the folder this process loaded it from, without putting that folder (or the
working directory, and whatever lies there) on its path."""


def _pipe() -> tuple[int, int]:
    """`os.pipe()` whose ends are above the standard descriptors 0-2: in a process started without stdin or stdout
    (a daemon, `python script.py <&- >&-`) a pipe end would be 0 or 1, which the child's own /dev/null stdin and
    stdout replace: the child would read and answer the wrong file, and the recorder say the writer process ended."""
    ends = []
    for fd in os.pipe():
        if fd > 2:
            ends.append(fd)
            continue
        ends.append(fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 3))
        os.close(fd)
    return ends[0], ends[1]


def _interpreter_flags() -> list[str]:
    """This interpreter's flags (-W, -X, -E, -I, -O, ...) for the child, less -S (without `site` the child would
    not find the packages it imports) and -X importtime (pages of timings from the child)."""
    flags = subprocess._args_from_interpreter_flags()
    out = []
    for flag, after in zip(flags, [*flags[1:], None], strict=True):
        if flag == "-S" or flag.startswith("importtime") or (flag == "-X" and after and after.startswith("importtime")):
            continue
        out.append(flag)
    return out


def _simreel_root() -> str:
    import simreel

    return os.path.dirname(os.path.dirname(os.path.abspath(simreel.__file__)))
