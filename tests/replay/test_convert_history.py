"""A control-mode conversion and the scene's history (`simreel.replay.history`): its output replays exactly, in
recorded order, only when the conversion stepped its episodes one after another in one scene, as the replay does."""

from __future__ import annotations

from support.maniskill_files import record_maniskill

from simreel.cli.main import main


def test_a_control_mode_conversion_asked_for_workers_runs_in_one_process(tmp_path, capsys):
    """Regression: with --workers 2 each process converted some episodes after others than the output holds before
    them; a grasp episode of the output then diverged from its own replay (PhysX results depend on the history)."""
    src = record_maniskill(tmp_path, "PickCube-v1", name="pick", episodes=4, steps=60, path="pick")
    out = tmp_path / "ee.h5"
    assert main(["convert", str(src), str(out), "--control-mode", "pd_ee_delta_pose", "--workers", "2", "-q"]) == 0
    assert "converted in one process, not 2" in capsys.readouterr().err
    assert main(["replay", str(out), "-q"]) == 0
    assert "4 exact" in capsys.readouterr().out
