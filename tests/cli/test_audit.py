"""`simreel audit --json` on storage that refuses the document: one line naming it."""

from __future__ import annotations

from support.small_disk import fill, small_disk

from simreel.cli.main import main


def test_a_full_disk_under_the_json_names_it(tmp_path, capsys):
    """Regression: it said "writing the output: the disk is full", naming no file."""
    with small_disk(tmp_path, 256) as disk:
        target = disk / "a.json"
        fill(disk, 0)
        assert main(["audit", "PickCube-v1", "--steps", "2", "--json", str(target), "-q"]) == 2
        captured = capsys.readouterr()
        assert captured.out and captured.err == (
            f"simreel audit: error: {target}: the disk is full: the report was not written; its findings are the "
            "lines above; free some space or write to another disk, then audit again\n")
        assert not target.exists()
