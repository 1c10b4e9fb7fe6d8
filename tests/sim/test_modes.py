"""`simreel.sim.modes`: a mistyped observation or control mode is one line with its close matches, found before
the env is built (ManiSkill found it seconds into the build and raised its own assertion)."""

from __future__ import annotations

import pytest

from simreel.cli.main import main
from simreel.errors import EnvBuildError
from simreel.sim.modes import check_modes, control_mode_error
from simreel.sim.user_code import import_mani_skill


@pytest.fixture(scope="module")
def tasks():
    import_mani_skill()
    from mani_skill.utils.registration import REGISTERED_ENVS

    return REGISTERED_ENVS


@pytest.mark.parametrize("obs_mode", ["state", "state_dict", "none", "rgb", "rgbd", "pointcloud", "sensor_data",
                                      "rgb+depth", "rgb+segmentation+state"])
def test_every_mode_maniskill_takes_passes(tasks, obs_mode):
    check_modes("PickCube-v1", tasks["PickCube-v1"].cls, obs_mode, "pd_ee_delta_pose", {})


def test_a_mistyped_mode_is_named_with_its_close_matches_without_building_the_env(tasks):
    cls = tasks["PickCube-v1"].cls
    with pytest.raises(EnvBuildError) as caught:
        check_modes("PickCube-v1", cls, "stat", None, {})
    assert str(caught.value).startswith("PickCube-v1: no obs mode 'stat'; did you mean state? the obs modes there "
                                        "are state, state_dict, none, sensor_data, pointcloud, rgbd, rgb, depth,")
    with pytest.raises(EnvBuildError, match=r"no obs mode 'rgb\+dpth'; did you mean rgbd, depth\?"):
        check_modes("PickCube-v1", cls, "rgb+dpth", None, {})
    with pytest.raises(EnvBuildError) as caught:
        check_modes("PickCube-v1", cls, None, "pd_joint_poss", {})
    assert str(caught.value).startswith("PickCube-v1: no control mode 'pd_joint_poss'; did you mean pd_joint_pos, "
                                        "pd_joint_pos_vel, pd_joint_delta_pos? the control modes there are ")
    # the robot the kwargs name: panda_stick has a mode panda has not
    check_modes("PickCube-v1", cls, None, "pd_ee_delta_pose_align", {"robot_uids": "panda_stick"})
    with pytest.raises(EnvBuildError, match="no control mode 'pd_ee_delta_pose_align'"):
        check_modes("PickCube-v1", cls, None, "pd_ee_delta_pose_align", {})


def test_maniskills_own_check_is_told_the_same_way():
    """A robot whose modes need its built articulation (Fetch): ManiSkill's assertion, in the same words."""
    said = control_mode_error("PickCube-v1", "pd_joint_poss not in supported modes: ['pd_joint_pos', 'pd_ee_pose']")
    assert str(said) == ("PickCube-v1: no control mode 'pd_joint_poss'; did you mean pd_joint_pos, pd_ee_pose? the control modes "
                         "there are pd_joint_pos, pd_ee_pose")
    assert control_mode_error("PickCube-v1", "some other assertion") is None


@pytest.mark.parametrize(("args", "said"), [
    (["--obs-mode", "stat"], "no obs mode 'stat'; did you mean state?"),
    (["--control-mode", "pd_joint_poss"], "no control mode 'pd_joint_poss'; did you mean pd_joint_pos,"),
    (["--control-mode", "pd_joint_poss", "--env-kwargs", '{"robot_uids": "fetch"}'],
     "no control mode 'pd_joint_poss'; did you mean pd_joint_pos,"),
], ids=["obs", "control", "control-maniskill-check"])
def test_record_says_it_in_one_line(tmp_path, capsys, args, said):
    assert main(["record", "PickCube-v1", "-o", str(tmp_path / "x.h5"), "-n", "1", "--render-backend", "none",
                 *args]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(f"simreel record: error: PickCube-v1: {said}")
    assert list(tmp_path.iterdir()) == []
