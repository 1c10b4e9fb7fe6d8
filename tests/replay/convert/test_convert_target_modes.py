"""Control-mode conversion to the modes that keep a target (`pd_joint_target_delta_pos`, `pd_ee_target_delta_pos`,
`pd_ee_target_delta_pose`), on two robots: the Panda (PickCube's grasp-and-lift demos) and Fetch (an arm swing, its
torso and mobile base holding still; its end-effector controller works in its torso's frame). Each action is the
delta from the live controller's kept target; the converted file holds that target in its states and replays
exact; a mode that cannot follow the demo (position only, where the demo turns the hand) is reported as such."""

from __future__ import annotations

import json

import pytest
from support.maniskill_files import record_maniskill

from simreel.cli.main import main
from simreel.formats import open_reader

STEPS = 30
DEMOS = {"panda": ("pick", {}), "fetch": ("arm", {"robot_uids": "fetch"})}
TARGET_STATE = {"pd_joint_target_delta_pos": "controller/arm/target_qpos",
                "pd_ee_target_delta_pos": "controller/arm/target_pose",
                "pd_ee_target_delta_pose": "controller/arm/target_pose"}


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("target_demos")
    made = {}

    def make(robot):
        if robot not in made:
            path, env_kwargs = DEMOS[robot]
            made[robot] = record_maniskill(folder, "PickCube-v1", name=robot, episodes=2, steps=STEPS, path=path,
                                           path_seed=102, env_kwargs=env_kwargs)
        return made[robot]

    return make


def _verifies(src, out, mode, report_path, capsys):
    assert main(["convert", str(src), str(out), "--control-mode", mode, "-q", "--report", str(report_path)]) == 0
    assert f"control pd_joint_pos -> {mode}" in capsys.readouterr().out
    report = json.loads(report_path.read_text())
    assert report["ok"] and report["written"] == [0, 1]
    for episode in report["episodes"]:
        assert episode["verdict"] in ("exact", "within_tolerance") and episode["first_divergence"] is None
        assert episode["checked"] == ["commanded pose", "end-effector pose", "object poses", "success"]
    return report


@pytest.mark.parametrize(("robot", "mode"), [("panda", "pd_joint_target_delta_pos"),
                                             ("panda", "pd_ee_target_delta_pose"),
                                             ("fetch", "pd_joint_target_delta_pos"),
                                             ("fetch", "pd_ee_target_delta_pose")])
def test_a_target_mode_conversion_verifies_and_replays_exact(demos, robot, mode, tmp_path, capsys):
    out = tmp_path / "converted.h5"
    report = _verifies(demos(robot), out, mode, tmp_path / "report.json", capsys)
    assert max(report["episodes"][0]["per_step"]["command/" + ("panda_hand_tcp" if robot == "panda" else
                                                              "gripper_link") + "[p]"]) < 1e-4
    with open_reader(out) as r:
        assert r.meta.control_mode == mode and TARGET_STATE[mode] in r.meta.state_layout
        target = r.read_episode(0).env_states[TARGET_STATE[mode]]
        assert target.shape[0] == STEPS + 1 and (target[1:] != target[0]).any()  # the kept target moves
    assert main(["replay", str(out), "-q"]) == 0
    assert "2 of 2 episode(s) verified (2 exact" in capsys.readouterr().out


def test_a_position_only_target_mode_that_cannot_turn_the_hand_is_not_verified(demos, tmp_path, capsys):
    """The pick demo turns the hand to the cube; pd_ee_target_delta_pos keeps the hand's orientation: the check says
    so (the rotation column), nothing is written, exit 1."""
    out = tmp_path / "pos.h5"
    assert main(["convert", str(demos("panda")), str(out), "--control-mode", "pd_ee_target_delta_pos", "-q",
                 "--report", str(tmp_path / "r.json")]) == 1
    assert f"0 of 2 episode(s) verified; 0 written to {out}; 2 left out by --keep" in capsys.readouterr().out
    report = json.loads((tmp_path / "r.json").read_text())
    for episode in report["episodes"]:
        assert episode["verdict"] == "diverged"
        assert episode["max_abs_error"]["ee/panda_hand_tcp[q]"] > 0.05  # the ee_rot tolerance
        assert episode["max_abs_error"]["ee/panda_hand_tcp[p]"] < 0.01  # the position it follows
    assert not out.exists()


NOT_FOLLOWED = {"panda": {"pd_joint_vel", "pd_ee_delta_pos", "pd_ee_target_delta_pos"},
                "fetch": {"pd_ee_delta_pos", "pd_ee_target_delta_pos"}}
"""The modes whose conversions of these demos are not verified with the default tolerances (docs/conversion.md's
table): position-only modes where the demos turn the hand; a velocity controller off the Panda's pick path by more
than 1 cm. Fetch's pd_joint_vel is left out of the sweep's claims: some of its swings verify, some do not."""


@pytest.mark.slow
@pytest.mark.parametrize("robot", list(DEMOS))
def test_every_mode_simreel_converts_on_both_robots_gives_the_documented_verdicts(demos, robot, tmp_path):
    from simreel.replay.convert.control import SUPPORTED
    from simreel.replay.convert.convert import convert_recording

    for mode in SUPPORTED["pd_joint_pos"]:
        report = convert_recording(demos(robot), tmp_path / f"{mode}.h5", control_mode=mode, keep="all")
        assert report.written == [0, 1] and len(report.episodes) == 2, mode
        if robot == "fetch" and mode == "pd_joint_vel":
            continue
        verified = [e.ok for e in report.episodes]
        assert verified == [mode not in NOT_FOLLOWED[robot]] * 2, (mode, [e.verdict for e in report.episodes])
