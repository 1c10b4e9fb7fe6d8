"""`simreel replay` over a dataset: files, folders and patterns of simreel and ManiSkill recordings as one work
list; one line per file and the episodes that did not verify; a damaged episode or file reported (exit 2) without
ending the run; the JSON report with one entry per file and per episode, each episode exactly once."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections import Counter

import h5py
import pytest
from support.maniskill_files import record_maniskill
from support.unreadable import link_loop, unreadable_copy

from simreel.cli.main import main


@pytest.fixture(scope="module")
def dataset(record, tmp_path_factory):
    """data/: PickCube (HDF5 and MCAP), StackCube, a ManiSkill RecordEpisode file, one with an altered action,
    one with a damaged episode, and a file that is no recording."""
    data = tmp_path_factory.mktemp("dataset") / "data"
    (data / "more").mkdir(parents=True)
    shutil.copy(record("PickCube-v1", 2, 8), data / "pick.h5")
    assert main(["convert", str(record("PickCube-v1", 1, 9, "--seed", "11")), str(data / "more" / "pick.mcap"),
                 "-q"]) == 0
    shutil.copy(record("StackCube-v1", 1, 6), data / "more" / "stack.h5")
    record_maniskill(data, "PickCube-v1", name="maniskill", episodes=2, steps=7)
    shutil.copy(record("PickCube-v1", 2, 8), data / "altered.h5")
    with h5py.File(data / "altered.h5", "r+") as f:
        f["traj_1/actions"][4] += 0.5
    shutil.copy(record("PickCube-v1", 2, 8), data / "damaged.h5")
    with h5py.File(data / "damaged.h5", "r+") as f:
        del f["traj_0/actions"]
    (data / "more" / "junk.mcap").write_text("not a recording")
    return data


def test_a_dataset_is_one_run_with_a_line_per_file_and_every_episode_once(dataset, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(dataset.parent)
    report = tmp_path / "r.json"
    code = main(["replay", "data", "--workers", "2", "--report", str(report), "-q"])
    out = capsys.readouterr().out
    assert code == 2, out  # a damaged episode and an unreadable file are bad input, after the run
    lines = out.splitlines()
    assert lines[0] == "replay of 7 recordings (2 env id(s)), mode actions: 10 episode(s), 77 steps"
    rows = {line.split()[0]: line.split()[1:] for line in lines[2:9]}
    assert rows["data/pick.h5"] == ["PickCube-v1", "2", "2", "0", "0", "0"]
    assert rows["data/maniskill.h5"] == ["PickCube-v1", "2", "2", "0", "0", "0"]
    assert rows["data/more/stack.h5"] == ["StackCube-v1", "1", "1", "0", "0", "0"]
    assert rows["data/altered.h5"] == ["PickCube-v1", "2", "1", "0", "1", "0"]
    assert rows["data/damaged.h5"] == ["PickCube-v1", "2", "1", "0", "0", "1"]
    assert " ".join(rows["data/more/junk.mcap"]) == "cannot be replayed: neither an HDF5 nor an MCAP file"
    text = "\n".join(lines)
    assert "data/altered.h5\n        1      8  diverged          step 4: " in text
    assert "data/damaged.h5\n        0      8  error             traj_0 lacks actions, which the recording's layout lists" in text
    assert "limit: contact forces not compared: the file holds none (1 of 7 files)" in text
    assert lines[-2] == ("8 of 10 episode(s) verified (8 exact, 0 within tolerance); 1 diverged; "
                         "1 could not be replayed; 1 file(s) unreadable")

    doc = json.loads(report.read_text())
    assert doc["ok"] is False and doc["complete"] is True and len(doc["files"]) == 7
    assert Counter((e["file"], e["index"]) for e in doc["episodes"]).most_common(1)[0][1] == 1
    assert len(doc["episodes"]) == 10
    by_file = {f["path"].split("/data/")[1]: f for f in doc["files"]}
    assert by_file["more/junk.mcap"]["error"] == "neither an HDF5 nor an MCAP file"
    assert by_file["maniskill.h5"]["limits"] and not by_file["pick.h5"]["limits"]
    diverged = [e for e in doc["episodes"] if e["verdict"] == "diverged"]
    assert [(e["file"].split("/data/")[1], e["index"], e["first_divergence"]["step"]) for e in diverged] == [
        ("altered.h5", 1, 4)]


def test_patterns_and_several_files_and_the_exit_status_of_a_clean_dataset(dataset, capsys, monkeypatch):
    monkeypatch.chdir(dataset)
    assert main(["replay", "pick.h5", "more/*.h5", "--episodes", "0", "-q"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("replay of 2 recordings (2 env id(s)), mode actions: 2 episode(s), 14 steps")
    assert main(["replay", "pick.h5", "altered.h5", "-q"]) == 1  # diverged, nothing unreadable
    capsys.readouterr()


def test_inspect_of_a_dataset_is_a_line_per_file(dataset, capsys, monkeypatch):
    monkeypatch.chdir(dataset)
    assert main(["inspect", "."]) == 2  # junk.mcap cannot be read
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["file", "env", "id"]
    assert any(line.startswith("maniskill.h5 ") and "ManiSkill" in line for line in lines)
    assert "more/junk.mcap  unreadable: neither an HDF5 nor an MCAP file" in lines
    assert lines[-1] == "7 recordings (1 unreadable): 10 episodes, 77 steps"
    assert main(["inspect", "pick.h5", "more/stack.h5", "--json"]) == 0
    summaries = json.loads(capsys.readouterr().out)
    assert [s["meta"]["env_id"] for s in summaries] == ["PickCube-v1", "StackCube-v1"]


def test_episodes_a_file_lacks_are_named_and_those_it_has_replayed(record, tmp_path, capsys, monkeypatch):
    """`--episodes` over files of different lengths: each replays the episodes it has, and a warning names those it
    lacks; asking for episodes no file has is one line."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "data").mkdir()
    shutil.copy(record("PickCube-v1", 2, 8), tmp_path / "data" / "two.h5")
    shutil.copy(record("StackCube-v1", 1, 6), tmp_path / "data" / "one.h5")
    capsys.readouterr()
    assert main(["replay", "data", "--episodes", "1,3", "-q"]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines()[-1] == "1 of 1 episode(s) verified (1 exact, 0 within tolerance); all verified"
    assert err == ("simreel replay: warning: data/one.h5: has none of the episodes --episodes names (no episode 1, 3): "
                   "nothing of it is replayed\n"
                   "simreel replay: warning: data/two.h5: has no episode 3 of those --episodes names: only its "
                   "episode(s) 1 are replayed\n")
    assert main(["replay", "data", "--episodes", "5", "-q"]) == 2
    assert capsys.readouterr().err == ("simreel replay: error: --episodes 5: none of the recordings has any of these "
                                       "episodes\n")


LOOP = "a symbolic link loop (following its links never reaches a file); fix or remove the link"
DENIED = "permission denied (this user may not read it)"


def _rows(out: str) -> dict[str, str]:
    """The lines of a run or an inspection by the file each starts with: the rest, its words joined by one space."""
    return {line.split()[0]: " ".join(line.split()[1:]) for line in out.splitlines() if line.strip()}


def test_a_symbolic_link_loop_in_a_dataset_is_reported_and_the_run_goes_on(record, tmp_path, capsys, monkeypatch):
    """Regression: `Path.resolve` raised RuntimeError for a loop (exit 3, nothing replayed), and a folder's scan
    skipped one without a word."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "data").mkdir()
    shutil.copy(record("PickCube-v1", 2, 8), tmp_path / "data" / "pick.h5")
    link_loop(tmp_path / "data" / "loop.mcap")  # and loop.other.mcap, its other half
    assert main(["replay", "data", "-q"]) == 2
    rows = _rows(capsys.readouterr().out)
    assert rows["data/pick.h5"] == "PickCube-v1 2 2 0 0 0"
    assert rows["data/loop.mcap"] == rows["data/loop.other.mcap"] == f"cannot be replayed: {LOOP}"
    assert main(["inspect", "data"]) == 2
    out = capsys.readouterr().out
    assert _rows(out)["data/loop.mcap"] == f"unreadable: {LOOP}"
    assert out.splitlines()[-1] == "3 recordings (2 unreadable): 2 episodes, 16 steps"


@pytest.mark.parametrize(("argv", "pick", "locked"), [
    (["replay", "data", "-q"], "PickCube-v1 2 2 0 0 0", f"cannot be replayed: {DENIED}"),
    (["inspect", "data"], "PickCube-v1 2 16 0 simreel HDF5 recording (format 1)", f"unreadable: {DENIED}"),
], ids=["replay", "inspect"])
def test_a_file_this_user_may_not_read_in_a_dataset_is_reported_and_the_run_goes_on(record, tmp_path, argv, pick,
                                                                                      locked):
    """Regression: the reader's open() raised PermissionError, which ended the run as a bug of simreel's (exit 3)
    before anything was replayed. Run as a shell would, where the file's mode bites (`support.unreadable`)."""
    (tmp_path / "data").mkdir()
    shutil.copy(record("PickCube-v1", 2, 8), tmp_path / "data" / "pick.h5")
    prefix = unreadable_copy(record("PickCube-v1", 2, 8), tmp_path / "data" / "locked.h5")
    done = subprocess.run([*prefix, sys.executable, "-m", "simreel", *argv], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)
    assert (done.returncode, done.stderr) == (2, ""), done.stdout
    rows = _rows(done.stdout)
    assert (rows["data/pick.h5"], rows["data/locked.h5"]) == (pick, locked), done.stdout
