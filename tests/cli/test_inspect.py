"""`simreel inspect`: what it prints of a recording."""

from __future__ import annotations

from simreel.cli.main import main


def test_inspect_file_without_frequencies(tmp_path, capsys):
    from simreel.episode import RecordingMeta
    from simreel.formats import open_writer

    open_writer(tmp_path / "api.h5", RecordingMeta(env_id="PickCube-v1")).close()
    assert main(["inspect", str(tmp_path / "api.h5")]) == 0
    assert "? Hz sim / ? Hz control" in capsys.readouterr().out
