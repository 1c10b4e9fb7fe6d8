"""The recorder's writer process (`simreel.recorders.writer_process`): the same file as a writer in the recorder's own
process, committed by the time `reset()` returns, and every way it can end — with the recorder, killed on its own,
on Ctrl-C to the whole process group, refused at the start — leaves the committed episodes readable and says what
happened in one line. (A full disk met in the writer process: tests/formats/test_durable.py.)"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from support.children import child_pids, running, wait_ended
from support.mcap_samples import synthetic_episode, synthetic_meta

from simreel.errors import RecordingFileError, UsageError
from simreel.formats import open_reader
from simreel.formats.hdf5.layout import sidecar_path
from simreel.recorders import RecordWrapper
from simreel.recorders.scene_book import SceneBook
from simreel.recorders.writer_process import ProcessWriter
from simreel.sim.make import make_env


def _record(path, writer_process: bool, seen: list[int] | None = None) -> None:
    """Three PickCube episodes of 6 steps (the second ended by a reset with a new seed, the last by close); `seen`
    gets how many episodes a reader finds in the file right after each reset returned."""
    rng = np.random.default_rng(0)
    rec = RecordWrapper(make_env("PickCube-v1"), path, writer_process=writer_process)
    for k in range(3):
        rec.reset(seed=k)
        if seen is not None:
            with open_reader(path) as r:
                seen.append(len(r))
        for _ in range(6):
            rec.step(rng.uniform(-1, 1, rec.action_space.shape).astype(np.float32))
    rec.close()
    assert [m.index for m in rec.episodes_committed] == [0, 1, 2]


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_the_writer_process_writes_what_the_recorder_would_and_commits_before_reset_returns(tmp_path, suffix):
    seen: list[int] | None = [] if suffix == ".h5" else None  # an MCAP file is read once it is finished
    _record(tmp_path / f"process{suffix}", True, seen)
    _record(tmp_path / f"inline{suffix}", False)
    assert seen in ([0, 1, 2], None)  # each reset returned with the episode it ended readable by another reader
    _assert_same_recordings(tmp_path / f"process{suffix}", tmp_path / f"inline{suffix}", 3)


def _assert_same_recordings(a_path: Path, b_path: Path, episodes: int) -> None:
    """Both files hold `episodes` undamaged episodes with the same metadata, actions, rewards, success, contact forces
    and states, bit for bit."""
    with open_reader(a_path) as a, open_reader(b_path) as b:
        assert len(a) == len(b) == episodes and a.damaged == b.damaged == []
        for m in a.episodes:
            x, y = a.read_episode(m.index), b.read_episode(m.index)
            assert x.meta.to_json() == y.meta.to_json()
            for name in ("actions", "rewards", "success", "contact_forces"):
                assert np.array_equal(getattr(x, name), getattr(y, name)), name
            assert x.env_states.keys() == y.env_states.keys()
            for key in x.env_states:
                assert np.array_equal(x.env_states[key], y.env_states[key]), key


def _recording(tmp_path, **popen):
    out = tmp_path / "rec.h5"
    proc = subprocess.Popen([sys.executable, "-m", "simreel", "record", "PickCube-v1", "-o", str(out), "-n", "1000",
                             "--max-steps", "10", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            **popen)
    deadline = time.monotonic() + 180
    while not sidecar_path(out).exists() or len(json.loads(sidecar_path(out).read_text())["episodes"]) < 2:
        assert proc.poll() is None, proc.communicate()[1]
        assert time.monotonic() < deadline, "fewer than 2 episodes committed in 180 s"
        time.sleep(0.05)
    return proc, out


def _committed_episodes_read(out, last_cut_short: bool = False) -> int:
    """How many episodes `out` holds, each read whole: 10 steps, but for the last one where the recording was
    stopped (Ctrl-C commits the running episode's steps so far)."""
    with open_reader(out) as r:
        for m in r.episodes:
            length = r.read_episode(m.index).length
            assert length == 10 or (last_cut_short and m.index == len(r) - 1 and 1 <= length < 10)
        return len(r)


def test_a_writer_process_killed_on_its_own_stops_the_recording_with_one_line(tmp_path):
    proc, out = _recording(tmp_path)
    [writer] = child_pids(proc.pid)
    os.kill(writer, signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    [line] = err.splitlines()
    assert line.startswith(f"simreel record: error: {out}: the writer process (pid {writer}) ended (exit status -9); "
                           "the episodes committed before it did are in the file")
    assert _committed_episodes_read(out) >= 2


def test_ctrl_c_to_the_whole_process_group_is_handled_by_the_recorder(tmp_path):
    """A terminal's Ctrl-C goes to the recorder's whole process group; the writer process, in a session of its own,
    is not in it: the recorder handles it and tells the writer what to keep."""
    proc, out = _recording(tmp_path, start_new_session=True)
    writers = child_pids(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    wait_ended(writers)
    assert _committed_episodes_read(out, last_cut_short=True) >= 2
    assert not (tmp_path / "rec.h5.partial").exists()  # closed properly: nothing left beside the file


def _writer_processes() -> list[int]:
    """The writer processes this process started that still run."""
    found = []
    for pid in child_pids(os.getpid()):
        try:
            if b"writer_process" in Path(f"/proc/{pid}/cmdline").read_bytes() and running(pid):
                found.append(pid)
        except OSError:
            continue
    return found


def test_a_recorder_that_refuses_its_target_leaves_no_writer_process(tmp_path):
    path = tmp_path / "taken.h5"
    path.write_bytes(b"someone's file")
    env = make_env("PickCube-v1")
    with pytest.raises(UsageError, match="already exists"):  # the writer's own error, from its process
        RecordWrapper(env, path)
    env.close()
    assert _writer_processes() == [] and path.read_bytes() == b"someone's file"


def _interrupt_waits(monkeypatch, *which: int) -> None:
    """Make the recorder's waits for an answer from its writer process number `which` (1: the next one) end in
    KeyboardInterrupt, as a Ctrl-C that lands there does (the answer is left in the pipe); the others read as usual."""
    receive = ProcessWriter._receive
    calls = []

    def maybe_interrupted(self, held=None):
        calls.append(None)
        if len(calls) in which:
            raise KeyboardInterrupt
        return receive(self, held)

    monkeypatch.setattr(ProcessWriter, "_receive", maybe_interrupted)


def test_ctrl_c_while_a_reset_waits_for_its_commit_does_not_leave_later_resets_a_step_behind(tmp_path, monkeypatch):
    """The answer a Ctrl-C left unread is read before the next one: the next reset still returns only once the
    episode it ended is committed (here the writer is held stopped for a second, so a stale answer would let it
    return first)."""
    path = tmp_path / "rec.h5"
    rec = RecordWrapper(make_env("PickCube-v1"), path)
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    rec.step(zero)
    writer = rec._writer._child.pid
    os.kill(writer, signal.SIGSTOP)  # so the reset's settle has to wait (the answer cannot be there before)
    _interrupt_waits(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        rec.reset(seed=1)
    os.kill(writer, signal.SIGCONT)
    rec.step(zero)
    os.kill(writer, signal.SIGSTOP)
    threading.Timer(1.0, os.kill, (writer, signal.SIGCONT)).start()
    rec.reset(seed=2)
    with open_reader(path) as r:
        assert [m.index for m in r.episodes] == [0, 1]
    assert [m.index for m in rec.episodes_committed] == [0, 1]
    rec.close()


def test_ctrl_c_while_the_writer_opens_its_file_leaves_nothing(tmp_path, monkeypatch):
    """Interrupted between asking the writer process to open the file and its answer: the child opened it, so it
    is told to drop it; no file, side file or child process stays (a later recording there is not refused)."""
    path = tmp_path / "rec.h5"
    env = make_env("PickCube-v1")
    _interrupt_waits(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        RecordWrapper(env, path)
    assert list(tmp_path.iterdir()) == [] and _writer_processes() == []
    RecordWrapper(env, path).close()
    assert path.exists()


@pytest.mark.parametrize("hangs", [False, True], ids=["exits", "hangs"])
def test_a_python_that_cannot_run_the_writer_is_one_clear_error(tmp_path, monkeypatch, hangs):
    """An application that embeds Python has another program as `sys.executable`: the writer process cannot start,
    and the recorder says so, and how to write in this process instead, rather than wait forever."""
    import re

    import simreel.recorders.writer_process as writer_process

    program = tmp_path / "not-python"
    program.write_text("#!/bin/sh\nexec sleep 60\n" if hangs else "#!/bin/sh\nexit 1\n")
    program.chmod(0o755)
    env = make_env("PickCube-v1")  # before: simreel's Vulkan probe runs sys.executable too
    monkeypatch.setattr(sys, "executable", str(program))
    monkeypatch.setattr(writer_process, "_START_SECONDS", 1 if hangs else 60)
    out = tmp_path / "out" / "rec.h5"
    out.parent.mkdir()
    how = "did not answer in 1 s" if hangs else "ended (exit status 1)"
    with pytest.raises(RecordingFileError, match=re.escape(
            f"{out}: the writer process ({program}) {how} before it opened the file; record with "
            "writer_process=False to write in this process")):
        RecordWrapper(env, out)
    monkeypatch.setattr(sys, "executable", None)  # what some embedding applications leave it
    with pytest.raises(RecordingFileError, match="the writer process \\(None\\) could not start"):
        RecordWrapper(env, out)
    env.close()
    assert not list(out.parent.iterdir())


def _write(w: ProcessWriter, episode) -> None:
    sink = w.begin_episode(episode.meta, episode.reset_block())
    sink.append(episode.steps_block())
    sink.commit(episode.meta)


def test_an_error_the_writer_met_is_not_lost_to_a_ctrl_c_and_stops_it_for_good(tmp_path, monkeypatch):
    """The writer process refuses a write (here: a second episode 0); the settle that would report it is cut by a
    Ctrl-C, and so is the next one (after a new checkpoint), after it read that answer: a later settle still raises
    the error, and so does every later write, as a writer in one process would."""
    meta = synthetic_meta(poses=False)
    first = synthetic_episode(meta, 0, 5)
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    _write(w, first)
    w.begin_episode(first.meta, first.reset_block())  # the same index again: refused in the child
    _interrupt_waits(monkeypatch, 1, 3)  # the first settle's wait, and the second's for its own answer
    with pytest.raises(KeyboardInterrupt):
        w.settle()
    try:
        w.checkpoint()  # reads what the child said before it sends: the error, where its answer is there already
    except UsageError as e:
        assert "episode 0 was already written" in str(e)  # noqa: PT017 - the error may come here or below
        monkeypatch.undo()  # the second interrupted wait is not waited for now: none later is interrupted
    else:
        with pytest.raises(KeyboardInterrupt):
            w.settle()  # read the first settle's answer (the error), then was cut waiting for the checkpoint's
    with pytest.raises(UsageError, match="episode 0 was already written"):
        w.settle()
    with pytest.raises(UsageError, match="episode 0 was already written"):
        _write(w, synthetic_episode(meta, 1, 5))
    w.close()
    assert [m.index for m in w.committed] == [0]
    with open_reader(tmp_path / "r.h5") as r:
        assert [m.index for m in r.episodes] == [0]


def test_a_settle_waits_for_what_was_sent_before_its_checkpoint(tmp_path):
    """A checkpoint marks what the next settle waits for (the writer held stopped for a second meanwhile, so a
    settle that did not wait would return first); a settle with no checkpoint outstanding waits for everything."""
    meta = synthetic_meta(poses=False)
    first, second = synthetic_episode(meta, 0, 5), synthetic_episode(meta, 1, 5)
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    _write(w, first)
    w.checkpoint()
    os.kill(w._child.pid, signal.SIGSTOP)
    threading.Timer(1.0, os.kill, (w._child.pid, signal.SIGCONT)).start()
    sink = w.begin_episode(second.meta, second.reset_block())  # after the checkpoint
    w.settle()
    assert [m.index for m in w.committed] == [0]
    sink.append(second.steps_block())
    sink.commit(second.meta)
    w.settle()
    assert [m.index for m in w.committed] == [0, 1]
    w.close()


def test_an_error_met_after_a_checkpoint_is_raised_by_the_next_write(tmp_path):
    """The settle waits for the checkpoint only, so an error in what was sent after it (a refused begin: a second
    episode 0) is not its to raise; the child tells it at once, and the next write raises it, not a later one."""
    meta = synthetic_meta(poses=False)
    first = synthetic_episode(meta, 0, 5)
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    _write(w, first)
    w.checkpoint()
    w.begin_episode(first.meta, first.reset_block())
    w.settle()
    assert w._recv_conn.poll(30)  # the child's news, once it has met the error
    with pytest.raises(UsageError, match="episode 0 was already written"):
        _write(w, synthetic_episode(meta, 1, 5))
    w.close()
    with open_reader(tmp_path / "r.h5") as r:
        assert [m.index for m in r.episodes] == [0]


def test_a_settle_after_one_a_ctrl_c_cut_waits_for_everything_sent_since(tmp_path, monkeypatch):
    """The answer the cut settle left unread is not this settle's: it asks anew (the writer held stopped for a
    second, so a settle that took the old answer would return first)."""
    meta = synthetic_meta(poses=False)
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    _write(w, synthetic_episode(meta, 0, 5))
    _interrupt_waits(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        w.settle()
    os.kill(w._child.pid, signal.SIGSTOP)
    threading.Timer(1.0, os.kill, (w._child.pid, signal.SIGCONT)).start()
    _write(w, synthetic_episode(meta, 1, 5))
    w.settle()
    assert [m.index for m in w.committed] == [0, 1]
    w.close()


@pytest.mark.parametrize("writer_process", [True, False], ids=["writer process", "in-process"])
def test_a_recorder_interrupted_after_its_file_was_opened_leaves_nothing(tmp_path, monkeypatch, writer_process):
    """Setting up goes on after the writer opened the file (scene fingerprints: seconds with many envs); a Ctrl-C
    there drops the new recording, so the next run is not refused."""
    path = tmp_path / "rec.h5"
    env = make_env("PickCube-v1")

    def interrupted(self, envs):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(SceneBook, "rebuilt", interrupted)
        with pytest.raises(KeyboardInterrupt):
            RecordWrapper(env, path, writer_process=writer_process)
    assert list(tmp_path.iterdir()) == [] and _writer_processes() == []
    RecordWrapper(env, path, writer_process=writer_process).close()
    assert path.exists()


def test_an_error_read_as_a_ctrl_c_lands_is_raised_by_close(tmp_path, monkeypatch):
    """A Ctrl-C held while an error answer is read comes out of that settle instead of the error; the error is
    raised by close, never swallowed (a full disk must not end as a silent exit 130)."""
    import signal

    import simreel.recorders.writer_process as writer_process

    meta = synthetic_meta(poses=False)
    first = synthetic_episode(meta, 0, 5)
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    _write(w, first)
    w.begin_episode(first.meta, first.reset_block())  # refused in the child
    rebuilt = writer_process.rebuilt_error

    def rebuilt_as_ctrl_c_lands(portable):
        signal.raise_signal(signal.SIGINT)  # held until the answer is noted
        return rebuilt(portable)

    monkeypatch.setattr(writer_process, "rebuilt_error", rebuilt_as_ctrl_c_lands)
    with pytest.raises(KeyboardInterrupt):
        w.settle()
    monkeypatch.setattr(writer_process, "rebuilt_error", rebuilt)
    with pytest.raises(UsageError, match="episode 0 was already written"):
        w.close()
    assert [m.index for m in w.committed] == [0]


def test_a_stopped_writer_process_does_not_make_ctrl_c_useless(tmp_path, monkeypatch):
    """Closing waits for the child with signals held, as a writer's own close does; a child that never answers (here
    stopped) is given `_STOP_SECONDS` once a Ctrl-C is held, then killed: one error, the file as a kill leaves it."""
    import simreel.io.durable as durable
    import simreel.recorders.writer_process as writer_process

    monkeypatch.setattr(writer_process, "_STOP_SECONDS", 1)
    meta = synthetic_meta(poses=False)
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    _write(w, synthetic_episode(meta, 0, 5))
    w.settle()
    os.kill(w._child.pid, signal.SIGSTOP)
    threading.Timer(0.3, signal.raise_signal, (signal.SIGINT,)).start()
    started = time.monotonic()
    try:
        with pytest.raises(RecordingFileError, match=r"the writer process \(pid \d+\) ended \(exit status -9\)"):
            w.close()
    finally:
        durable._received.clear()  # the Ctrl-C was noted for a command's next unit of work; there is none here
    assert time.monotonic() - started < 20
    with open_reader(tmp_path / "r.h5") as r:
        assert [m.index for m in r.episodes] == [0]


def test_a_ctrl_c_as_an_episode_begins_leaves_no_episode_unfinished(tmp_path):
    """A Ctrl-C held while the recorder sends the writer process a new episode comes out once the recorder has
    noted the episode: close then ends it (discarded, no step), and the file names no unfinished episode."""
    import signal

    path = tmp_path / "rec.mcap"
    rec = RecordWrapper(make_env("PickCube-v1"), path)
    rec.reset(seed=0)
    rec.step(np.zeros(rec.action_space.shape, np.float32))
    connection = rec._writer._send_conn
    send = connection.send

    def send_then_ctrl_c(message):
        send(message)
        if message[0] == "begin":
            signal.raise_signal(signal.SIGINT)  # held by the send's deferred_signals

    connection.send = send_then_ctrl_c
    with pytest.raises(KeyboardInterrupt):
        rec.reset(seed=1)
    connection.send = send
    rec.close()
    with open_reader(path) as r:
        assert [m.index for m in r.episodes] == [0] and r.unfinished == []


def test_a_block_whose_captures_do_not_pickle_is_converted_here_and_written_the_same(tmp_path):
    """A recorder hands a one-env block's captures to the writer process unconverted (`StepBlock.captured`); a capture
    that does not pickle (here a lock in an info value, which records as zeros either way) must not stop the recording:
    that block is converted in the recorder's process and written as the child would have written it."""
    from simreel.model.blocks import StepBlock
    from simreel.sim.step_rows import ScalarRows

    meta = synthetic_meta(poses=False)
    episode = synthetic_episode(meta, 0, 4)
    source = ScalarRows(1, ["success", "fail", "is_grasped", "elapsed_steps"],
                        [(n, n.removeprefix("info/"), d) for n, d in (("success", bool), ("fail", bool),
                                                                     ("info/is_grasped", bool), ("info/elapsed_steps", np.int32))])
    captures = [[[0.5 * t], [False], [t == 3], [t > 1], [False], [threading.Lock()] if t == 0 else [True], [t + 1]]
                for t in range(4)]
    steps = episode.steps_block()
    plain = {name: a for name, a in steps.arrays.items() if name not in source.names}
    expected = {name: rows[:, 0] for name, rows in source(captures).items()}
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    sink = w.begin_episode(episode.meta, episode.reset_block())
    sink.append(StepBlock(plain, 4, ((source, captures, 0),)))
    sink.commit(episode.meta)
    w.close()
    with open_reader(tmp_path / "r.h5") as r:
        written = r.read_episode(0)
    assert written.info["is_grasped"].tolist() == [False, True, True, True]  # the lock's step: zeros
    for name, rows in expected.items():
        got = written.info[name.removeprefix("info/")] if name.startswith("info/") else getattr(written, name)
        assert got.dtype == rows.dtype and np.array_equal(got, rows), name
    np.testing.assert_array_equal(written.actions, episode.actions)


def test_row_sources_travel_once_and_a_full_table_forgets_the_least_used_without_losing_a_block(tmp_path, monkeypatch):
    """A block's captures name their row sources by number, each source sent to the writer process once; a scene the
    env rebuilds brings a new state source, and past `_MAX_SOURCES` the child forgets the least recently used. With
    room for only a block's four, every rebuilt scene makes it forget one: the file must still be the one a writer in
    the recorder's process writes."""
    import simreel.recorders.writer_process as writer_process

    monkeypatch.setattr(writer_process, "_MAX_SOURCES", 4)
    learned = []

    def noting_lessons(send):
        def noted(message, *args, **kwargs):
            if message[0] == "learn":
                learned.append(message[1])
            send(message, *args, **kwargs)
        return noted

    for process in (True, False):
        rng = np.random.default_rng(0)
        rec = RecordWrapper(make_env("PickCube-v1", env_kwargs={"reconfiguration_freq": 1}), tmp_path / f"{process}.h5",
                            writer_process=process)
        if process:
            rec._writer._send = noting_lessons(rec._writer._send)
        for k in range(4):
            rec.reset(seed=k)
            for _ in range(3):
                rec.step(rng.uniform(-1, 1, rec.action_space.shape).astype(np.float32))
        rec.close()
    assert len(learned) == len(set(learned)) == 3 + 4  # scalars, contacts, actions once; one state source per scene
    _assert_same_recordings(tmp_path / "True.h5", tmp_path / "False.h5", 4)


def test_a_row_source_that_does_not_pickle_falls_back_to_converting_here(tmp_path):
    """A row source is sent to the writer process once, before the first block that uses it; one that does not
    pickle (a user's subclass holding a lock) must not stop the recording either: its block is converted here."""
    from simreel.model.blocks import StepBlock
    from simreel.sim.step_rows import ScalarRows

    class Locked(ScalarRows):
        def __init__(self, *args):
            super().__init__(*args)
            self.lock = threading.Lock()

    meta = synthetic_meta(poses=False)
    episode = synthetic_episode(meta, 0, 4)
    source = Locked(1, ["success", "fail", "is_grasped", "elapsed_steps"],
                    [(n, n.removeprefix("info/"), d) for n, d in (("success", bool), ("fail", bool),
                                                                 ("info/is_grasped", bool), ("info/elapsed_steps", np.int32))])
    captures = [[[0.5 * t], [False], [t == 3], [t > 1], [False], [True], [t + 1]] for t in range(4)]
    plain = {name: a for name, a in episode.steps_block().arrays.items() if name not in source.names}
    w = ProcessWriter(tmp_path / "r.h5").open(meta)
    sink = w.begin_episode(episode.meta, episode.reset_block())
    sink.finish(episode.meta, StepBlock(plain, 4, ((source, captures, 0),)))
    w.close()
    with open_reader(tmp_path / "r.h5") as r:
        assert r.read_episode(0).info["elapsed_steps"].tolist() == [1, 2, 3, 4]


_RECORD_SCRIPT = """
import sys
from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env
env = RecordWrapper(make_env("PickCube-v1", max_episode_steps=3), sys.argv[1])
env.reset(seed=0)
for _ in range(3):
    env.step(env.action_space.sample())
env.close()
"""


def test_a_recorder_in_a_process_without_stdin_and_stdout_writes_its_file(tmp_path):
    """Regression: in a Python process started without descriptors 0 and 1 (a daemon, ``<&- >&-``), the writer
    child's pipes took them and the child's own /dev/null stdin and stdout replaced them: "the writer process ended"
    at the first episode, no file."""
    script, out = tmp_path / "rec.py", tmp_path / "r.h5"
    script.write_text(_RECORD_SCRIPT)
    done = subprocess.run(["sh", "-c", 'exec "$@" <&- >&-', "sh", sys.executable, str(script), str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    with open_reader(out) as reader:
        assert [ep.length for ep in reader.episodes] == [3]
