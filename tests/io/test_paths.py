"""`simreel.io.paths`: a symbolic link loop told apart from a missing file, a real path that never raises for
one, and a file the file system will not open for reading as a `RecordingFileError` naming it and why."""

from __future__ import annotations

import pytest
from support.unreadable import link_loop

from simreel.errors import RecordingFileError
from simreel.io.paths import SYMLINK_LOOP, is_symlink_loop, read_head, real_path


def test_a_symbolic_link_loop_is_told_apart_from_a_missing_file_and_a_dangling_link(tmp_path):
    loop = link_loop(tmp_path / "loop.h5")
    (tmp_path / "file.h5").write_bytes(b"x")
    (tmp_path / "dangling.h5").symlink_to("gone.h5")
    link_loop(tmp_path / "dir")
    assert is_symlink_loop(loop) and is_symlink_loop(tmp_path / "dir" / "inside.h5")
    assert not any(is_symlink_loop(tmp_path / name) for name in ("file.h5", "missing.h5", "dangling.h5"))


def test_real_path_follows_links_and_never_raises_for_a_loop(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file.h5").write_bytes(b"x")
    (tmp_path / "link.h5").symlink_to("file.h5")
    link_loop(tmp_path / "loop.h5")
    assert real_path("link.h5") == tmp_path / "file.h5"
    assert real_path("loop.h5").is_absolute()  # where Path.resolve raises RuntimeError (Python 3.11)


def test_a_loop_read_is_one_error_naming_it(tmp_path):
    loop = link_loop(tmp_path / "loop.mcap")
    with pytest.raises(RecordingFileError) as refused:
        read_head(loop, 8)
    assert str(refused.value) == f"{loop}: {SYMLINK_LOOP}"


def test_read_head_gives_the_first_bytes_or_fewer_of_a_short_file(tmp_path):
    (tmp_path / "long.h5").write_bytes(b"0123456789")
    (tmp_path / "short.h5").write_bytes(b"abc")
    assert read_head(tmp_path / "long.h5", 8) == b"01234567" and read_head(tmp_path / "short.h5", 8) == b"abc"
