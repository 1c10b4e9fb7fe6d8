"""Which recordings a command's inputs name (`simreel.datasets.inputs`): files as given, folders searched below,
glob patterns; each file once; never the scratch files of a running HDF5 recording, nor the staged output a killed
merge or filter left."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write
from support.unreadable import link_loop

from simreel.cli.main import main
from simreel.datasets.inputs import expand_inputs, shown_path
from simreel.errors import UsageError


def _touch(path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")


def test_files_folders_and_patterns_each_once_in_the_order_given(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("data/b.h5", "data/a.mcap", "data/deep/c.HDF5", "data/notes.txt", "data/a.json",
                 "data/run.h5.partial/traj_3.h5", "other/x.h5"):
        _touch(tmp_path / name)
    found = expand_inputs(["other/x.h5", "data", "data/*.h5", "other/x.h5"])
    assert [(os.path.relpath(p), explicit) for p, explicit in found] == [
        ("other/x.h5", True), ("data/a.mcap", False), ("data/b.h5", False), ("data/deep/c.HDF5", False)]
    assert all(p.is_absolute() for p, _ in found)


def test_a_named_file_is_kept_even_if_missing_so_its_reader_can_say_why(tmp_path):
    ((path, explicit),) = expand_inputs([tmp_path / "missing.h5"])
    assert path == tmp_path / "missing.h5" and explicit


def test_a_symbolic_link_loop_is_kept_for_its_reader_to_name(tmp_path, monkeypatch):
    """Named or found in a folder or by a pattern, a loop is listed like a file (its reader says what it is), never
    skipped without a word nor a crash of `Path.resolve`."""
    monkeypatch.chdir(tmp_path)
    _touch(tmp_path / "data" / "a.h5")
    link_loop(tmp_path / "data" / "loop.mcap")
    found = expand_inputs(["data/loop.mcap", "data", "data/*.mcap"])
    assert [(os.path.relpath(p), explicit) for p, explicit in found] == [
        ("data/loop.mcap", True), ("data/a.h5", False), ("data/loop.other.mcap", False)]


@pytest.mark.parametrize(("spec", "kind"), [("empty", "folder"), ("*.mcap", "pattern")])
def test_a_folder_or_pattern_without_recordings_is_bad_input(tmp_path, monkeypatch, spec, kind):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("no recordings here")
    with pytest.raises(UsageError, match=f"no recordings .* found in this {kind}"):
        expand_inputs([spec])


def test_shown_paths_are_relative_below_the_working_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert shown_path(tmp_path / "d" / "a.h5") == "d/a.h5"
    assert shown_path("/elsewhere/a.h5") == "/elsewhere/a.h5"


def test_a_recordings_identity_covers_the_sidecar_a_reader_reads(tmp_path):
    """The JSON sidecar beside the name given is part of the recording (a ManiSkill file's episodes and seeds):
    changing it changes the identity, also through a link that has its own sidecar; a link without one is its
    target's recording."""
    from simreel.datasets.inputs import file_identity

    target = tmp_path / "demos.h5"
    target.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    target.with_suffix(".json").write_text('{"episodes": []}')
    link = tmp_path / "link.h5"
    link.symlink_to(target)
    assert file_identity(link) == file_identity(target) == (108 + 16, file_identity(target)[1])
    before = file_identity(target)
    target.with_suffix(".json").write_text('{"episodes": [1]}')
    assert file_identity(target) != before
    link.with_suffix(".json").write_text('{"episodes": [2]}')
    linked = file_identity(link)
    os.utime(link.with_suffix(".json"), ns=(0, linked[1] + 10**9))  # edited later
    assert file_identity(link) != linked and file_identity(link)[0] == 108 + 17


def _killed_filter(data: Path, src: Path) -> Path:
    """The staged output (``.kept.simreel-PID@HOST.h5``) a filter of `src` into ``data/kept.h5`` leaves when it is
    killed with two episodes written."""
    support = Path(__file__).resolve().parents[1] / "support"
    child = subprocess.Popen([sys.executable, str(support / "paused_copy.py"), "filter", str(src), "-o",
                              str(data / "kept.h5"), "--episodes", "0-3"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "copying"  # two episodes written to its staged output
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=60)
    leftover = data / f".kept.simreel-{child.pid}@{socket.gethostname()}.h5"
    assert leftover.is_file() and not (data / "kept.h5").exists()
    return leftover


def leftover_pid(leftover: Path) -> int:
    """The PID in the staging name of what `_killed_filter` left."""
    return int(leftover.stem.split(".simreel-")[1].split("@")[0])


def test_a_killed_filters_staged_output_is_skipped_by_scans_and_named_once(tmp_path, capsys):
    """Regression: a `kill -9`'d merge or filter leaves its staged output (``.OUT.simreel-PID@HOST.h5``) beside OUT, and
    `simreel inspect DIR` / `replay DIR` took it for a recording. A scan skips it and says so once on stderr; named
    explicitly it is still read (to inspect what is left)."""
    data = tmp_path / "data"
    data.mkdir()
    meta = synthetic_meta()
    src = write(data / "src.h5", meta, [synthetic_episode(meta, i, 3) for i in range(4)])
    leftover = _killed_filter(data, src)

    for spec in (data, data / "*.h5", f"{data}/.*.h5"):
        capsys.readouterr()
        if spec == f"{data}/.*.h5":
            with pytest.raises(UsageError, match="no recordings"):
                expand_inputs([spec])
        else:
            assert expand_inputs([spec, data]) == [(src, False)]
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"simreel: warning: skipped {shown_path(leftover)}: ")
        assert "interrupted" in err and "delete them" in err
    assert expand_inputs([leftover]) == [(leftover, True)]
    assert main(["inspect", str(data)]) == 0
    out = capsys.readouterr().out
    assert "src.h5" in out and "simreel-" not in out and "1 recording" in out


def test_the_next_filter_of_the_same_output_removes_what_a_killed_one_left(tmp_path, capsys):
    """Regression: the staged outputs of killed runs stayed beside OUT for good (scans skip them, saying so)."""
    data = tmp_path / "data"
    data.mkdir()
    meta = synthetic_meta()
    src = write(data / "src.h5", meta, [synthetic_episode(meta, i, 3) for i in range(4)])
    leftover = _killed_filter(data, src)
    assert leftover.with_suffix(".json").is_file()
    host = socket.gethostname()
    running = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    kept = [data / f".other.simreel-1@{host}.h5",  # another output's
            data / f".kept.simreel-{running.pid}@{host}.h5",  # a run's still checking (its writer closed)
            data / f".kept.simreel-{leftover_pid(leftover)}@not-{host}.h5"]  # another machine's: it may go on
    for path in kept:
        path.write_bytes(leftover.read_bytes())
    legacy = data / f".kept.simreel-{leftover_pid(leftover)}.h5"  # an earlier simreel's, its process gone: removed
    legacy.write_bytes(leftover.read_bytes())
    capsys.readouterr()
    try:
        assert main(["filter", str(src), "-o", str(data / "kept.h5"), "--episodes", "0-3", "-q"]) == 0
    finally:
        running.kill()
        running.wait()
    out = capsys.readouterr().out
    assert not leftover.exists() and not leftover.with_suffix(".json").exists()  # with its sidecar
    assert all(path.exists() for path in kept) and not legacy.exists() and (data / "kept.h5").is_file()
    assert f"note: removed {shown_path(leftover)}: the unchecked output of a merge or filter of kept.h5 killed " \
           "before it finished" in out


def test_a_hard_link_of_a_file_given_or_found_is_read_once(tmp_path, monkeypatch):
    """A file reached under two names (a hard link beside it, or named once and found again in a folder) is one
    input, as a symbolic link to it is: `replay` and `inspect` read it once."""
    monkeypatch.chdir(tmp_path)
    _touch(tmp_path / "data/a.h5")
    (tmp_path / "data/b.h5").hardlink_to(tmp_path / "data/a.h5")
    found = expand_inputs(["data/a.h5", "data"])
    assert [(os.path.relpath(p), explicit) for p, explicit in found] == [("data/a.h5", True)]
