"""`simreel audit`: the leaky example task is flagged with the key and the cause; its fixed twin passes."""

from __future__ import annotations

import json

from simreel.cli.main import main


def test_leaky_task_is_flagged(tmp_path, capsys):
    out = tmp_path / "audit.json"
    assert main(["audit", "SimreelLiftCubeLeaky-v1", "--import", "simreel.tasks", "--json", str(out)]) == 1
    text = capsys.readouterr().out
    assert "evaluate()['height_error'] differs after restore: task state not in the state dict — declare it" in text
    assert "goal_height" in text  # the attribute that holds the leaked state is named
    doc = json.loads(out.read_text())
    assert doc["ok"] is False
    keys = {(f["kind"], f["key"]) for f in doc["findings"]}
    assert ("restore_evaluate", "info/height_error") in keys
    assert ("restore_obs", "obs/extra/goal_height") in keys
    assert all({"kind", "key", "detail"} <= set(f) for f in doc["findings"])


def test_fixed_twin_passes(tmp_path, capsys):
    out = tmp_path / "audit.json"
    assert main(["audit", "SimreelLiftCube-v1", "--json", str(out), "--steps", "10"]) == 0
    assert "no findings" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["ok"] is True and doc["findings"] == []
    assert any("round-trips" in c for c in doc["checks"])
    assert any("layout is the same for seeds" in c for c in doc["checks"])


def test_controller_state_is_checked(capsys):
    assert main(["audit", "PickCube-v1", "--control-mode", "pd_ee_target_delta_pos", "--steps", "8"]) == 0
    out = capsys.readouterr().out
    assert "controller state survives a restore (controller/arm/target_pose)" in out
    assert "ManiSkill's set_state_dict() ignores the controller state" in out


def test_a_real_leak_in_a_builtin_task_is_found(capsys):
    """ManiSkill 3.0.1's RotateValve samples the valve's rest position per episode into `rest_qpos`, which its
    state dict does not hold: after a restore, the valve rotation (and the reward) follow the other episode."""
    assert main(["audit", "RotateValveLevel0-v1", "--steps", "5", "-q"]) == 1
    out = capsys.readouterr().out
    assert "restore_evaluate   info/valve_rotation" in out
    assert "task attributes that still differ after the restore: rest_qpos" in out
