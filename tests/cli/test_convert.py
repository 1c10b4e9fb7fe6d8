"""`simreel convert`: HDF5 ⇄ MCAP through the CLI, bit-exact, and one-line errors for bad arguments."""

from __future__ import annotations

from pathlib import Path

import h5py
import pytest
from support.mcap_samples import assert_same_episode, long_sample, synthetic_episode, synthetic_meta, write
from support.small_disk import fill, small_disk

from simreel.cli.main import main
from simreel.formats import open_reader


def _source(tmp_path: Path, suffix: str, *, poses: bool = True) -> tuple[Path, list]:
    meta = synthetic_meta(poses=poses)
    episodes = [synthetic_episode(meta, i, T) for i, T in enumerate((4, 70, 1))]
    return write(tmp_path / f"src{suffix}", meta, episodes), episodes


@pytest.mark.parametrize(("first", "second"), [(".h5", ".mcap"), (".mcap", ".h5"), (".mcap", ".mcap"), (".h5", ".h5")])
def test_convert_both_ways_is_bit_exact(tmp_path, capsys, first, second):
    src, episodes = _source(tmp_path, first)
    mid, out = tmp_path / f"mid{second}", tmp_path / f"out{first}"
    assert main(["convert", str(src), str(mid), "-q"]) == 0
    assert main(["convert", str(mid), str(out), "-q"]) == 0
    printed = capsys.readouterr().out
    assert f"converted 3 episode(s), 75 steps, {src} → {mid}" in printed
    for path in (mid, out):
        with open_reader(path) as r:
            assert r.meta.to_json() == synthetic_meta().to_json()
            for want in episodes:
                assert_same_episode(r.read_episode(want.meta.index), want)


def test_convert_without_poses_notes_what_tf_shows(tmp_path, capsys):
    src, _ = _source(tmp_path, ".h5", poses=False)
    assert main(["convert", str(src), str(tmp_path / "out.mcap"), "-q"]) == 0
    assert "shows the actors and articulation roots of the state dict only" in capsys.readouterr().out


def test_a_copy_to_mcap_says_it_draws_no_scene(tmp_path, capsys):
    src, _ = _source(tmp_path, ".h5")
    assert main(["convert", str(src), str(tmp_path / "out.mcap"), "-q"]) == 0
    assert "a copy holds no shapes for Foxglove and Rerun (/scene, /robot_description)" in capsys.readouterr().out
    assert main(["convert", str(src), str(tmp_path / "out.h5"), "-q"]) == 0
    assert "/scene" not in capsys.readouterr().out


def test_progress_bar_counts_episodes_on_a_terminal_only(tmp_path, capsys, monkeypatch):
    src, _ = _source(tmp_path, ".h5")
    assert main(["convert", str(src), str(tmp_path / "piped.mcap")]) == 0
    assert capsys.readouterr().err == ""  # not a terminal (a log, CI): no bar
    import io
    import sys

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    assert main(["convert", str(src), str(tmp_path / "out.mcap")]) == 0
    assert "3/3" in sys.stderr.getvalue()


@pytest.mark.parametrize(("option", "value"), [("--episodes", ""), ("--count", "0"), ("--report", ""),
                                               ("--shader", ""), ("--sim-backend", "")])
def test_a_conversion_option_given_empty_or_zero_to_a_copy_is_refused(tmp_path, capsys, option, value):
    """Regression: `--episodes ""` (an unset shell variable) or `--count 0` was taken for "not given" and the copy
    wrote every episode without a word, where `--episodes 0` or `--count 1` is refused."""
    src, _ = _source(tmp_path, ".h5")
    assert main(["convert", str(src), str(tmp_path / "out.mcap"), "-q", option, value]) == 2
    assert capsys.readouterr().err == (f"simreel convert: error: {option} apply to a conversion: add --obs-mode and/or "
                                       "--control-mode (without them, convert copies IN to another format as it is)\n")
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("extra", [[], ["--obs-mode", "state"]], ids=["copy", "conversion"])
def test_an_empty_out_is_one_line_naming_it(tmp_path, capsys, extra):
    """Regression: `simreel convert IN "$UNSET"` said ".: unknown recording suffix ''" (the working folder)."""
    src, _ = _source(tmp_path, ".h5")
    assert main(["convert", str(src), "", "-q", *extra]) == 2
    assert capsys.readouterr().err == ("simreel convert: error: an empty path names no recording (an unset shell "
                                       "variable?); name a .h5 or .mcap file\n")


def test_overwrite_replaces_output(tmp_path):
    src, episodes = _source(tmp_path, ".h5")
    (tmp_path / "out.mcap").write_bytes(b"old")
    assert main(["convert", str(src), str(tmp_path / "out.mcap"), "--overwrite", "-q"]) == 0
    with open_reader(tmp_path / "out.mcap") as r:
        assert len(r) == len(episodes)


@pytest.mark.parametrize(
    ("out", "message"),
    [("exists.mcap", "exists.mcap already exists; pass --overwrite"), ("missing/out.mcap", "does not exist")],
)
def test_poses_checks_out_before_building_the_env(tmp_path, monkeypatch, out, message):
    """Regression: `convert --poses` built the env before finding that OUT could not be written."""
    from simreel.datasets.copy import convert
    from simreel.errors import UsageError

    def no_env(meta):
        raise AssertionError("the env was built before OUT was checked")

    src, _ = _source(tmp_path, ".h5", poses=False)
    (tmp_path / "exists.mcap").write_bytes(b"keep me")
    with pytest.raises(UsageError, match=message):
        convert(src, tmp_path / out, transform=no_env)
    assert (tmp_path / "exists.mcap").read_bytes() == b"keep me"


def test_an_episode_that_does_not_fit_the_layout_is_one_line_and_leaves_no_output(tmp_path, capsys):
    """Regression: the MCAP writer's layout check raised a bare ValueError (a traceback from the CLI)."""
    meta = synthetic_meta()
    src = write(tmp_path / "src.h5", meta, [synthetic_episode(meta, 0, 4), synthetic_episode(meta, 1, 4)])
    with h5py.File(src, "a") as f:  # a hand-edited file: 1 contact channel where the layout says 2
        forces = f["traj_1/contact_forces"][()]
        del f["traj_1/contact_forces"]
        f["traj_1/contact_forces"] = forces[:, :1]
    assert main(["convert", str(src), str(tmp_path / "out.mcap"), "-q"]) == 2
    err = capsys.readouterr().err
    # the reader checks every episode against the file's own layout before a writer sees it
    assert err == (f"simreel convert: error: {src}: traj_1/contact_forces is float32 (4, 1, 3), the layout says "
                   "float32 (4, 2, 3)\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src.h5", "src.json"]


@pytest.mark.parametrize("suffix", [".mcap", ".h5"])
def test_convert_copies_an_episode_of_many_blocks_bit_exact(tmp_path, suffix):
    src, episodes = long_sample(tmp_path / "src.h5")
    out = tmp_path / f"out{suffix}"
    assert main(["convert", str(src), str(out), "-q"]) == 0
    with open_reader(out) as r:
        assert [m.length for m in r.episodes] == [3, 9000, 5]
        for want in episodes:
            assert_same_episode(r.read_episode(want.meta.index), want)


@pytest.mark.parametrize("suffix", [".mcap", ".h5"])
def test_a_block_that_fails_its_checksum_mid_episode_leaves_no_output(tmp_path, capsys, suffix):
    """Episode 1's actions are damaged in its third block, after two blocks of it were written: one line naming
    the damage, exit 2, and no output file (nor side files) left."""
    from support.damage import corrupt_chunk

    src, _ = long_sample(tmp_path / "src.h5")
    corrupt_chunk(src, "traj_1/actions", chunk=8, rows=1000)  # rows 8000-8999
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["convert", str(src), str(tmp_path / f"out{suffix}"), "-q"]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(f"simreel convert: error: {src}: ") and "traj_1/actions" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_poses_of_a_file_without_env_states_is_one_line(tmp_path, capsys):
    """A ManiSkill file recorded without env states (`record_env_state=False`) is valid input; `--poses`, which
    computes every body's pose from the states, ended in `internal error: StopIteration` (exit 3)."""
    from support.maniskill_files import record_maniskill

    src = record_maniskill(tmp_path, "PickCube-v1", name="nostate", episodes=1, steps=3, record_env_state=False)
    capsys.readouterr()  # ManiSkill's own warnings while recording
    assert main(["convert", str(src), str(tmp_path / "out.mcap"), "--poses", "-q"]) == 2
    assert capsys.readouterr().err == (
        f"simreel convert: error: --poses: {src} holds no env states, from which the poses are computed; convert it "
        "without --poses (or replay it with `simreel replay -o` first, which records the states it reaches)\n")
    assert not (tmp_path / "out.mcap").exists()


def test_the_help_names_every_tracking_tolerance_group(capsys):
    from simreel.replay.convert.tracking import TRACKING_GROUPS

    with pytest.raises(SystemExit):
        main(["convert", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert all(f"{group} (" in text or f"{group}," in text for group in TRACKING_GROUPS)


def test_the_help_says_count_is_applied_before_keep(capsys):
    """--count N converts the first N episodes; --keep then chooses among them: the help must not read as "N kept"
    (`--keep success --count 1` writes none when the first episode has no success)."""
    with pytest.raises(SystemExit):
        main(["convert", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert ("convert only the first N of those episodes; --keep then chooses which of them are written (N converted, "
            "at most N written)") in text


def test_a_full_disk_under_the_report_alone_names_the_report_and_keeps_the_output(record, tmp_path, capsys):
    """Regression: it said "writing the output: the disk is full", though the output was written and kept."""
    out = tmp_path / "out.mcap"
    with small_disk(tmp_path, 256) as disk:
        report = disk / "r.json"
        fill(disk, 0)
        capsys.readouterr()
        assert main(["convert", str(record("PickCube-v1", 1, 5)), str(out), "--obs-mode", "state",
                     "--report", str(report), "-q"]) == 2
        captured = capsys.readouterr()
        assert captured.err == (f"simreel convert: error: {report}: the disk is full: the report was not written; "
                                f"{out} was written and kept; free some space or write to another disk, then convert "
                                "again with --overwrite for the report\n")
        assert sorted(p.name for p in disk.iterdir() if not p.name.startswith("filler")) == []
    assert open_reader(out).meta.env_id == "PickCube-v1"


SUPPORT = Path(__file__).resolve().parents[1] / "support"


@pytest.mark.parametrize("command", [["convert", "{src}", "{out}"], ["recover", "{src}", "-o", "{out}"]],
                         ids=["convert", "recover-o"])
@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_kill_9_mid_copy_leaves_nothing_at_out_and_the_next_copy_clears_what_it_left(tmp_path, command, suffix):
    """OUT is written under a hidden staging name beside it and moved there complete: a copy killed with -9 after
    two of its three episodes were written leaves no OUT (it once left a file holding those two, which inspected
    clean and merged as if whole); the next copy to OUT removes the killed one's staging file."""
    import signal
    import subprocess
    import sys

    src, episodes = _source(tmp_path, ".h5")
    out = tmp_path / f"out{suffix}"
    args = [a.format(src=src, out=out) for a in command]
    child = subprocess.Popen([sys.executable, str(SUPPORT / "paused_copy.py"), *args], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "copying"
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=60)
    finally:
        child.kill()
        child.communicate()
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["src.h5", "src.json"]
    assert [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]  # the killed copy's, under a hidden name
    assert main([*args, "-q"] if command[0] == "convert" else args) == 0
    with open_reader(out) as r:
        assert len(r.episodes) == len(episodes)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
