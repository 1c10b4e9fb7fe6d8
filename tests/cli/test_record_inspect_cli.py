"""The record/inspect commands: real runs, and one clear line + exit 2 for every kind of bad input."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from simreel.cli.main import main


def _simreel(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simreel", *args], capture_output=True, text=True)


def test_help_is_instant_and_imports_nothing_heavy():
    code = (
        "import sys, time; t = time.perf_counter(); from simreel.cli.main import build_parser; build_parser(); "
        "heavy = [m for m in ('mani_skill', 'sapien', 'torch', 'rerun', 'h5py', 'gymnasium') if m in sys.modules]; "
        "print(heavy, time.perf_counter() - t)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    heavy, seconds = out.stdout.split("] ")
    assert heavy == "[", f"simreel --help imported {heavy}]"
    assert float(seconds) < 0.5
    t = time.perf_counter()
    assert _simreel("--help").returncode == 0
    assert time.perf_counter() - t < 3  # whole interpreter start included; mani_skill alone costs ~3 s


def test_record_then_inspect(tmp_path, capsys):
    out = tmp_path / "pc.h5"
    assert main(["record", "PickCube-v1", "-o", str(out), "-n", "2", "--seed", "7", "--max-steps", "10", "-q"]) == 0
    assert "recorded 2 episode(s), 20 steps" in capsys.readouterr().out
    assert main(["inspect", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [e["seed"] for e in summary["episodes"]] == [7, 8]
    assert summary["total_steps"] == 20
    assert summary["meta"]["state_layout"]["actors/cube"] == {"shape": [13], "dtype": "float32"}
    assert summary["meta"]["command"].startswith(f"simreel record PickCube-v1 -o {out} -n 2")
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "env_states/actors/cube" in text and "PickCube-v1" in text


@pytest.mark.parametrize(
    "args,message",
    [
        (["record", "PickCub-v1", "-o", "{tmp}/x.h5"], "unknown ManiSkill env id 'PickCub-v1': did you mean PickCube-v1"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--contacts", "panda/nose:cube"], "unknown body 'panda/nose'"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--contacts", "cube"], "bad contact pair 'cube'"),
        (["record", "PickCube-v1", "-o", "{tmp}/no/such/dir/x.h5"], "does not exist"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.txt"], "unknown recording suffix '.txt'"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "nosuchmod:f"], "cannot import nosuchmod"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "-n", "0"], "--episodes must be ≥ 1"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "-n", "two"], "argument -n/--episodes: invalid int value"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--env-kwargs", "[1]"], "expected a JSON object"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--import", "{tmp}/missing.py"], "missing.py"),
        (["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/broken.py:f"], "broken.py"),
        (["record", "TwoRobotPickCube-v1", "-o", "{tmp}/x.h5"], "Dict action space (a multi-agent task)"),
        (["inspect", "{tmp}/missing.h5"], "missing.h5: no such file"),
        (["inspect", "{tmp}/junk.h5"], "neither an HDF5 nor an MCAP file"),
    ],
    ids=["unknown-env", "unknown-body", "bad-pair", "no-dir", "bad-suffix", "bad-policy", "zero-episodes",
         "non-int", "bad-json", "bad-import", "broken-policy-file", "multi-agent", "missing-file", "junk-file"],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    (tmp_path / "junk.h5").write_text("not a recording")
    (tmp_path / "broken.py").write_text("raise RuntimeError('oops')\n")
    out = _simreel(*[a.format(tmp=tmp_path) for a in args])
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    assert message in lines[0]


def test_existing_output_is_kept_without_overwrite(tmp_path):
    out = tmp_path / "keep.h5"
    assert _simreel("record", "PushCube-v1", "-o", str(out), "--max-steps", "5", "-q").returncode == 0
    before = out.read_bytes()
    again = _simreel("record", "PushCube-v1", "-o", str(out), "--max-steps", "5", "-q")
    assert again.returncode == 2 and "already exists; pass --overwrite" in again.stderr
    assert out.read_bytes() == before


def test_random_policy_is_reproducible_from_the_seed(tmp_path, capsys):
    from simreel.formats import open_reader

    for name in ("a.h5", "b.h5"):
        assert main(["record", "PushCube-v1", "-o", str(tmp_path / name), "--seed", "4", "--max-steps", "6", "-q"]) == 0
    with open_reader(tmp_path / "a.h5") as a, open_reader(tmp_path / "b.h5") as b:
        assert (a.read_episode(0).actions == b.read_episode(0).actions).all()


def test_policy_from_a_file(tmp_path, capsys):
    (tmp_path / "my_policy.py").write_text(
        "import numpy as np\n\ndef still(env, obs):\n    return np.zeros(env.action_space.shape, np.float32)\n"
    )
    out = tmp_path / "p.h5"
    assert main(["record", "PushCube-v1", "-o", str(out), "--policy", f"{tmp_path}/my_policy.py:still",
                 "--max-steps", "3", "-q"]) == 0
    from simreel.formats import open_reader

    with open_reader(out) as r:
        assert not r.read_episode(0).actions.any()


def test_an_internal_error_is_one_line_and_exit_3(monkeypatch, capsys):
    import simreel.cli.inspect as inspect_cmd

    def broken(args):
        raise RuntimeError("boom")

    monkeypatch.setattr(inspect_cmd, "run", broken)
    assert main(["inspect", "whatever.h5"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["simreel inspect: internal error: RuntimeError: boom (rerun with --debug for the traceback, "
                   "and please report it)"]


def test_inspect_file_without_frequencies(tmp_path, capsys):
    from simreel.episode import RecordingMeta
    from simreel.formats import open_writer

    open_writer(tmp_path / "api.h5", RecordingMeta(env_id="PickCube-v1")).close()
    assert main(["inspect", str(tmp_path / "api.h5")]) == 0
    assert "? Hz sim / ? Hz control" in capsys.readouterr().out
