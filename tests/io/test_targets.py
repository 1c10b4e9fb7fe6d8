"""`simreel.io.targets`: the one rule for every output file, distinct outputs, atomic small files."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from support.unreadable import link_loop

from simreel.errors import UsageError
from simreel.io.targets import check_distinct, check_output, staged_output, write_text_atomic

LOOP = "a symbolic link loop (following its links never reaches a file); fix or remove the link"
SPECIAL = "a pipe, device or socket, not a regular file; simreel writes whole files, so name a file to write"


@pytest.mark.parametrize(
    ("target", "overwrite", "message"),
    [
        ("new.json", False, None),
        ("old.json", True, None),
        ("old.json", False, "{tmp}/old.json already exists; pass --overwrite to replace it (overwrite=True from Python)"),
        ("dir", False, "--report {tmp}/dir: that is a folder; name the file to write"),
        ("dir", True, "--report {tmp}/dir: that is a folder; name the file to write"),
        ("missing/r.json", True, "cannot write {tmp}/missing/r.json: folder {tmp}/missing does not exist"),
        ("old.json/r.json", True, "cannot write {tmp}/old.json/r.json: {tmp}/old.json is not a folder"),
        ("loop.json", False, "cannot write --report {tmp}/loop.json: " + LOOP),
        ("loop.json", True, "cannot write --report {tmp}/loop.json: " + LOOP),
        ("fifo.json", False, "cannot write --report {tmp}/fifo.json: it is " + SPECIAL),
        ("fifo.json", True, "cannot write --report {tmp}/fifo.json: it is " + SPECIAL),
        ("null.json", True, "cannot write --report {tmp}/null.json: it is " + SPECIAL),
    ],
)
def test_check_output(tmp_path, target, overwrite, message):
    (tmp_path / "old.json").write_text("mine")
    (tmp_path / "dir").mkdir()
    link_loop(tmp_path / "loop.json")
    os.mkfifo(tmp_path / "fifo.json")
    (tmp_path / "null.json").symlink_to(os.devnull)  # written through, it would replace /dev/null (as root)
    before = sorted(tmp_path.iterdir())
    if message is None:
        assert check_output(tmp_path / target, overwrite=overwrite, option="--report") == tmp_path / target
    else:
        with pytest.raises(UsageError) as e:
            check_output(tmp_path / target, overwrite=overwrite, option="--report")
        assert str(e.value) == message.format(tmp=tmp_path)
    assert sorted(tmp_path.iterdir()) == before and (tmp_path / "old.json").read_text() == "mine"


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_name_longer_than_the_file_system_takes_is_one_line(tmp_path, overwrite):
    """A name past 255 bytes fails every call that names it (ENAMETOOLONG, an internal error where it surfaced): it is
    refused here, before any work, saying which name; 255 bytes is still a name."""
    long = tmp_path / ("é" * 128 + ".json")  # 261 bytes in 133 characters: the limit is in bytes
    with pytest.raises(UsageError) as e:
        check_output(long, overwrite=overwrite, option="--report")
    assert str(e.value) == (f"cannot write --report {long}: its name is 261 bytes long, and the file system takes "
                            "names of 255 bytes at most; choose a shorter name")
    with pytest.raises(UsageError, match="a folder name in it is 300 bytes long"):
        check_output(tmp_path / ("d" * 300) / "r.json", overwrite=overwrite)
    with pytest.raises(UsageError, match=r"the name of the \.partial file beside it is 258 bytes long"):
        check_output(tmp_path / ("s" * 250), overwrite=overwrite, side_paths=[tmp_path / ("s" * 250 + ".partial")])
    assert check_output(tmp_path / ("n" * 255), overwrite=overwrite) == tmp_path / ("n" * 255)
    assert not list(tmp_path.iterdir())


def test_a_side_file_is_named_as_what_the_recording_would_replace(tmp_path):
    (tmp_path / "out.json").write_text("mine")
    with pytest.raises(UsageError) as e:
        check_output(tmp_path / "out.h5", overwrite=False, side_paths=[tmp_path / "out.json"])
    assert str(e.value) == (f"{tmp_path}/out.json already exists and writing out.h5 would replace it; "
                            "pass --overwrite to replace it (overwrite=True from Python)")


def test_a_side_file_that_is_a_pipe_is_refused_even_with_overwrite(tmp_path):
    os.mkfifo(tmp_path / "out.json")
    with pytest.raises(UsageError) as e:
        check_output(tmp_path / "out.h5", overwrite=True, side_paths=[tmp_path / "out.json"])
    assert str(e.value) == f"cannot write {tmp_path}/out.h5: {tmp_path}/out.json, which writing it replaces, is " + SPECIAL


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_folder_is_refused(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(UsageError, match="is not writable"):
            check_output(folder / "r.json", overwrite=True)
    finally:
        folder.chmod(0o700)


@pytest.mark.parametrize(
    ("outputs", "message"),
    [
        ({"-o": ["in.h5"]}, "-o in.h5 is the recording; write it to another file"),
        ({"--report": ["in.json"]}, "--report in.json is a file of the recording; write it to another file"),
        ({"-o": ["out.h5", "out.json"], "--report": ["out.json"]},
         "--report out.json is also written by -o; write it to another file"),
        ({"-o": ["out.h5", "out.json"], "--report": ["report.json"]}, None),
    ],
)
def test_check_distinct(tmp_path, monkeypatch, outputs, message):
    monkeypatch.chdir(tmp_path)
    if message is None:
        check_distinct(outputs, ["in.h5", "in.json"], input_label="the recording")
        return
    with pytest.raises(UsageError) as e:
        check_distinct(outputs, ["in.h5", "in.json"], input_label="the recording")
    assert str(e.value) == message


def test_check_distinct_compares_a_symbolic_link_loop_as_its_path(tmp_path, monkeypatch):
    """A loop is no file, but comparing it with others must not fail (Python 3.11's `Path.resolve` raises
    `RuntimeError` for one): `check_output` or the reader says what it is."""
    monkeypatch.chdir(tmp_path)
    link_loop(tmp_path / "loop.h5")
    check_distinct({"-o": ["loop.h5"]}, ["in.h5"])
    with pytest.raises(UsageError, match="^-o loop.h5 is the input; write it to another file$"):
        check_distinct({"-o": ["loop.h5"]}, [tmp_path / "loop.h5"])


def test_write_text_atomic_replaces_whole_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    path = tmp_path / "r.json"
    write_text_atomic(path, "one")
    write_text_atomic(path, "two")
    assert path.read_text() == "two" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]

    def full(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OSError):
        write_text_atomic(path, "three")
    assert path.read_text() == "two" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


def test_a_file_written_atomically_has_the_permissions_open_would_give_it(tmp_path):
    """Regression: sidecars and reports were 0600 (mkstemp's), unreadable to the other users of a shared dataset
    whose .h5 files are 0644."""
    import stat

    for mask, mode in ((0o022, 0o644), (0o077, 0o600)):
        old = os.umask(mask)
        try:
            write_text_atomic(tmp_path / "s.json", "{}")
        finally:
            os.umask(old)
        assert stat.S_IMODE((tmp_path / "s.json").stat().st_mode) == mode


def test_a_staged_output_at_a_symbolic_link_replaces_the_link_and_leaves_the_linked_file(tmp_path):
    """A link named as an output is replaced by the new file, as every recording writer replaces one: `view --save
    X --overwrite` and `video --overwrite` wrote through it, replacing the file it led to (a recording became an
    .rrd, then an mp4). The temporary file goes beside the link, so the rename never crosses file systems."""
    from simreel.io.targets import staged_output

    (tmp_path / "elsewhere").mkdir()
    real = tmp_path / "elsewhere" / "real.h5"
    real.write_text("a recording")
    link = tmp_path / "link.rrd"
    link.symlink_to(real)
    with staged_output(link, overwrite=True) as partial:
        assert partial.parent == tmp_path
        partial.write_text("new")
    assert not link.is_symlink() and link.read_text() == "new" and real.read_text() == "a recording"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["elsewhere", "link.rrd", "real.h5"]


_KILLED_WRITER = """
import sys, time
from pathlib import Path
from simreel.io.targets import open_text_atomic, staged_output
out = Path(sys.argv[2])
with staged_output(out, overwrite=False) if sys.argv[1] == "staged" else open_text_atomic(out):
    print(*out.parent.glob(".*"), flush=True)  # its temporary file, the folder's one hidden file
    time.sleep(120)
"""


@pytest.mark.parametrize(("kind", "name", "suffix"), [("staged", "out.mp4", ".partial.mp4"),
                                                     ("atomic", "report.json", ".tmp")])
def test_the_temporary_file_a_killed_run_left_is_removed_by_the_next_write_of_its_file(tmp_path, kind, name, suffix):
    """kill -9 runs no cleanup: a run writing OUT leaves its hidden temporary file beside it. The next write of OUT on
    this machine removes it, and keeps those of live processes, of other machines and any other file."""
    out = tmp_path / name
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, kind, str(out)], stdout=subprocess.PIPE, text=True)
    left = Path(proc.stdout.readline().strip())
    proc.kill()
    proc.wait()
    assert left.exists() and left.name.startswith(f".{name}.{proc.pid}@")
    host = socket.gethostname()
    kept = [tmp_path / f".{name}.{os.getpid()}@{host}.abcd1234{suffix}",  # a live process's (this one)
            tmp_path / f".{name}.{proc.pid}@not-{host}.abcd1234{suffix}",  # another machine's
            tmp_path / f".{name}.{proc.pid}@{host}.notes{suffix}",  # not a name simreel makes
            tmp_path / f".other.{proc.pid}@{host}.abcd1234{suffix}"]  # another file's
    for path in kept:
        path.write_text("kept")
    if kind == "staged":
        with staged_output(out, overwrite=False) as partial:
            partial.write_text("new")
    else:
        write_text_atomic(out, "new")
    assert out.read_text() == "new" and not left.exists()
    assert all(path.read_text() == "kept" for path in kept)


@pytest.mark.parametrize("kind", ["staged", "atomic"])
def test_a_file_of_a_long_name_is_written_through_a_temporary_name_the_file_system_takes(tmp_path, kind):
    """The process tag makes a temporary file's name longer than its file's: a 240-byte name (of 255 allowed) is cut
    and digested there, so it is written as any other."""
    out = tmp_path / ("r" * 235 + ".json")
    if kind == "staged":
        with staged_output(out, overwrite=False) as partial:
            partial.write_text("whole")
    else:
        write_text_atomic(out, "whole")
    assert out.read_text() == "whole" and [p.name for p in tmp_path.iterdir()] == [out.name]


def test_a_temporary_file_whose_lock_is_held_is_kept_whatever_its_name_says(tmp_path):
    """A process of another PID namespace (a container sharing the host name) may name a PID that is gone here: its
    temporary file is locked while it writes, and a locked one is never removed; once free, it is."""
    import fcntl

    out = tmp_path / "out.json"
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    live = tmp_path / f".out.json.{int(gone.stdout)}@{socket.gethostname()}.abcd1234.tmp"
    live.write_text("another container's, being written")
    fd = os.open(live, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        write_text_atomic(out, "one")
        assert live.exists()
    finally:
        os.close(fd)
    write_text_atomic(out, "two")
    assert not live.exists() and out.read_text() == "two"
