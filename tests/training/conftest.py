"""Recordings of three tasks for the training room's tests, made once per session: PickCube-v1 (HDF5, observations,
a delta control mode), PushCube-v1 (MCAP, observations, an end-effector delta mode) and StackCube-v1 (HDF5,
state-only, an absolute joint mode)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support.nudged import nudged_copy

from simreel.cli.main import main


@pytest.fixture(scope="session")
def three_tasks(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("training")
    made = {}
    for name, env_id, out, extra in (
        ("pick", "PickCube-v1", "pick.h5", ["-n", "3", "--max-steps", "30", "--record-obs"]),
        ("push", "PushCube-v1", "push.mcap", ["-n", "3", "--max-steps", "25", "--record-obs",
                                              "--control-mode", "pd_ee_delta_pos"]),
        ("stack", "StackCube-v1", "stack.h5", ["-n", "2", "--max-steps", "20", "--control-mode", "pd_joint_pos"]),
    ):
        made[name] = folder / out
        assert main(["record", env_id, "-o", str(made[name]), "--seed", "5", "--render-backend", "none", "-q",
                     *extra]) == 0
    return made


@pytest.fixture(scope="session")
def nudged(three_tasks, tmp_path_factory) -> tuple[Path, Path]:
    """A copy of the PickCube recording whose episode 1 had one action nudged, and its replay report (episodes 0
    and 2 exact, 1 diverged)."""
    folder = tmp_path_factory.mktemp("verdicts")
    rec = nudged_copy(three_tasks["pick"], folder / "nudged.h5")
    report = folder / "report.json"
    assert main(["replay", str(rec), "--report", str(report), "-q"]) == 1
    return rec, report
