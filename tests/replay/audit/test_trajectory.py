"""Auditing along real trajectories finds a leak that shows only after the cube is lifted, which the random-action
audit misses, and names the step and the phase; the fixed task is clean along the same trajectories."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.tasks.lift_cube import LiftCubeStageLeakyEnv

STAGE = "SimreelLiftCubeStageLeaky-v1"


def _lifted_at(path) -> int:
    """The first step after which the recorded cube stands `lift_threshold` above its resting height."""
    with open_reader(path) as r:
        episode = r.read_episode(0)
    z = episode.env_states["actors/cube"][1:, 2]
    threshold = LiftCubeStageLeakyEnv.cube_half_size + LiftCubeStageLeakyEnv.lift_threshold
    assert (z >= threshold).any()
    return int(np.argmax(z >= threshold))


def _findings(path) -> dict[str, dict]:
    return {f["key"]: f for f in json.loads(path.read_text())["findings"]}


def test_the_random_action_audit_misses_the_stage_leak(tmp_path, capsys):
    assert main(["audit", STAGE, "--json", str(tmp_path / "random.json")]) == 0
    assert "no findings" in capsys.readouterr().out


def test_the_audit_along_a_recording_finds_it_and_names_the_step(record, tmp_path, capsys):
    path = record(STAGE, 1, 40)
    lifted_at = _lifted_at(path)
    out = tmp_path / "along.json"
    assert main(["audit", "--trajectory", str(path), "--json", str(out)]) == 1
    findings = _findings(out)
    lifted = findings["info/lifted"]
    assert (lifted["kind"], lifted["step"]) == ("restore_evaluate", lifted_at)
    assert lifted["phase"] == f"episode 0 of {path}, grasped"
    assert "task attributes that still differ after the restore: lifted" in lifted["detail"]
    assert all(f["step"] >= lifted_at for f in findings.values())  # nothing before the lift
    text = capsys.readouterr().out
    assert f"info/lifted [step {lifted_at}, episode 0 of {path}, grasped]" in text
    assert "checked: restore-equivalence at" in text and f"points along episode 0 of {path}" in text


def test_the_audit_along_the_scripted_policy_finds_the_same_step(record, tmp_path):
    lifted_at = _lifted_at(record(STAGE, 1, 40))  # recorded with seed 3
    out = tmp_path / "policy.json"
    assert main(["audit", STAGE, "--policy", "scripted", "--seed", "3", "--json", str(out)]) == 1
    lifted = _findings(out)["info/lifted"]
    assert (lifted["step"], lifted["phase"]) == (lifted_at, "seed 3 with --policy scripted, grasped")


def test_the_fixed_task_is_clean_along_its_trajectories(record, capsys):
    assert main(["audit", "--trajectory", str(record("SimreelLiftCube-v1", 1, 20)), "-q"]) == 0
    assert main(["audit", "SimreelHeteroDrawer-v1", "--policy", "scripted", "--every", "2", "-q"]) == 0


@pytest.mark.parametrize(("args", "message"), [
    ([], "name the task to audit (ENV_ID), or a recording with --trajectory"),
    ([STAGE, "--episodes", "2"], "--episodes needs --policy or --trajectory"),
    ([STAGE, "--policy", "scripted", "--episodes", "0-2"], "--episodes with --policy is a number of episodes"),
    ([STAGE, "--policy", "scripted", "--every", "0"], "--every and --episodes must be >= 1"),
])
def test_bad_options_are_one_line_errors(args, message, capsys):
    assert main(["audit", *args]) == 2
    assert message in capsys.readouterr().err


def test_an_audit_along_a_file_with_a_damaged_episode_names_it_instead_of_skipping_it(tmp_path, capsys):
    """Regression: the damaged episode was left out silently and the audit along the rest said "no findings"."""
    path = tmp_path / "two.mcap"
    assert main(["record", "PickCube-v1", "-o", str(path), "-n", "2", "--seed", "0", "--max-steps", "4", "-q"]) == 0
    data = bytearray(path.read_bytes())
    seed = data.index(b'"seed": 1', data.index(b"simreel.episode.1"))  # in episode 1's metadata
    data[seed + 8] = ord("7")  # valid JSON, the wrong number: its record's checksum tells
    path.write_bytes(data)
    capsys.readouterr()
    assert main(["audit", "--trajectory", str(path), "--steps", "2"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"simreel audit: error: {path}: damaged, cannot be audited along: record simreel.episode.1: the record does not "
        f"match its checksum (damaged); name the others with --episodes; `simreel recover {path}` keeps its intact "
        "episodes"]
    assert main(["audit", "--trajectory", str(path), "--steps", "2", "--episodes", "0"]) == 0
