"""Bad input to `simreel replay` / `simreel audit`: exit 2 and one line on stderr that says what and how to fix."""

from __future__ import annotations

import dataclasses

import pytest

from simreel.cli.main import main
from simreel.formats import open_reader, open_writer


@pytest.fixture(scope="module")
def rec(record):
    return record("PickCube-v1", 2, 20)


def _run(capsys, args):
    try:
        code = main(args)
    except SystemExit as e:  # argparse
        code = e.code
    err = capsys.readouterr().err.strip()
    return code, err


@pytest.mark.parametrize(
    "args,message",
    [
        (["replay", "{tmp}/nope.h5"], "nope.h5: no such file"),
        (["replay", "{tmp}/junk.h5"], "neither an HDF5 nor an MCAP file"),
        (["replay", "{rec}", "--episodes", "7"], "no episode 7 (episodes: 0, 1)"),
        (["replay", "{rec}", "--episodes", "x"], "bad episode list 'x'"),
        (["replay", "{rec}", "--mode", "states", "--resync", "5"], "--resync works with --mode actions only"),
        (["replay", "{rec}", "--resync", "0"], "--resync must be >= 1, got 0"),
        (["replay", "{rec}", "--workers", "0"], "--workers must be >= 1, got 0"),
        (["replay", "{rec}", "--atol", "-1"], "argument --atol: must be a finite number >= 0, got -1"),
        (["replay", "{rec}", "--tol", "speed=1"], "expected GROUP=NUMBER with GROUP one of pos"),
        (["replay", "{rec}", "--mode", "sideways"], "argument --mode: invalid choice: 'sideways'"),
        (["replay", "{rec}", "-o", "{rec}", "--overwrite"], "is the recording being replayed"),
        (["replay", "{rec}", "-o", "{tmp}/exists.h5"], "exists.h5 already exists; pass --overwrite"),
        (["replay", "{rec}", "-o", "{tmp}/out.txt"], "unknown recording suffix '.txt'"),
        (["replay", "{rec}", "--report", "{tmp}/no/dir/r.json"], "does not exist"),
        (["replay", "{rec}", "--import", "no_such_module_xyz"], "no module named 'no_such_module_xyz'"),
        (["audit", "PickCub-v1"], "unknown ManiSkill env id 'PickCub-v1': did you mean PickCube-v1"),
        (["audit", "PickCube-v1", "--steps", "0"], "--steps must be >= 1, got 0"),
        (["audit", "PickCube-v1", "--json", "{tmp}/no/dir/a.json"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, rec, args, message):
    (tmp_path / "junk.h5").write_bytes(b"not a recording at all")
    (tmp_path / "exists.h5").write_bytes(b"")
    args = [a.format(tmp=tmp_path, rec=rec) for a in args]
    code, err = _run(capsys, [*args, "-q"] if args[0] == "replay" else args)
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert message in err


def test_a_recording_of_another_layout_is_refused(tmp_path, capsys, rec):
    """A file whose episodes do not fit the env it names (another task version, a hand-edited file)."""
    bad = tmp_path / "mislabelled.h5"
    with open_reader(rec) as r, open_writer(bad, dataclasses.replace(r.meta, env_id="PushCube-v1", state_layout={})) as w:
        w.write_episode(r.read_episode(0))
    code, err = _run(capsys, ["replay", str(bad), "-q"])
    assert code == 2
    assert "the rebuilt PushCube-v1 has another state layout than the recording" in err
    assert "actors/goal_site: recorded (13,) float32, replay absent" in err
