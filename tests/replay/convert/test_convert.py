"""Control-mode conversion, verified per step (`simreel.replay.convert.convert`, `simreel convert --control-mode`), on
pd_joint_pos demos made with ManiSkill's own RecordEpisode: PickCube (grasp-and-lift planned with IK), StackCube,
PegInsertionSide and an articulation task (SimreelHeteroDrawer's cabinets) along smooth joint paths. Both target
modes verify with per-step tracking errors in the report; a wrong gain is caught at the step it starts; filters,
provenance and the written file are checked; what simreel wrote replays exact."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.maniskill_files import record_maniskill

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.replay.convert.control import ConvertedAction, converter_for
from simreel.replay.convert.convert import convert_recording
from simreel.replay.convert.tracking import DEFAULT_TRACKING_TOLERANCES

TASKS = {
    "PickCube-v1": "pick",
    "StackCube-v1": "smooth",
    "PegInsertionSide-v1": "smooth",  # merged views in the registry, the robot is panda_wristcam
    "SimreelHeteroDrawer-v1": "smooth",  # an articulation (merged cabinets), rebuilt at every reset
}
MODES = ("pd_joint_delta_pos", "pd_ee_delta_pose")
STEPS = 45
PATH_SEED = 102
"""Paths 102 and 103 keep every task's arm clear of the scene; path 101 drives PegInsertionSide's arm against it
(see test_a_demo_the_target_mode_cannot_follow_is_reported)."""


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    """`demos(env_id)` → a RecordEpisode file of 2 pd_joint_pos demos of `STEPS` steps (made once per task)."""
    folder = tmp_path_factory.mktemp("demos")
    made: dict[str, Path] = {}

    def make(env_id: str) -> Path:
        if env_id not in made:
            if env_id.startswith("Simreel"):
                import simreel.tasks  # noqa: F401  (registers the task for ManiSkill's gym.make)
            made[env_id] = record_maniskill(folder, env_id, name=env_id.split("-")[0], episodes=2, steps=STEPS,
                                            path=TASKS[env_id], path_seed=PATH_SEED)
        return made[env_id]

    return make


def _tasks():
    return [pytest.param(env_id, mode, marks=[] if (env_id, mode) in (("PickCube-v1", m) for m in MODES) else
                         [pytest.mark.slow], id=f"{env_id}-{mode}") for env_id in TASKS for mode in MODES]


@pytest.mark.parametrize(("env_id", "mode"), _tasks())
def test_a_conversion_verifies_with_per_step_tracking_errors(demos, env_id, mode, tmp_path, capsys):
    src, out, report_path = demos(env_id), tmp_path / "converted.h5", tmp_path / "report.json"
    assert main(["convert", str(src), str(out), "--control-mode", mode, "-q", "--report", str(report_path)]) == 0
    printed = capsys.readouterr().out
    assert f"control pd_joint_pos -> {mode}" in printed and "2 of 2 episode(s) verified; 2 written" in printed
    report = json.loads(report_path.read_text())
    assert report["ok"] and report["tolerances"] == DEFAULT_TRACKING_TOLERANCES
    for episode in report["episodes"]:
        assert episode["verdict"] in ("exact", "within_tolerance") and episode["first_divergence"] is None
        assert episode["checked"] == ["commanded pose", "end-effector pose", "object poses", "success"]
        per_step = episode["per_step"]
        assert len(per_step["ee/panda_hand_tcp[p]"]) == STEPS + 1 and len(per_step["success"]) == STEPS
        # the report lists the keys that differ; an exact one (PegInsertionSide, pd_joint_delta_pos) is left out
        assert max(per_step["ee/panda_hand_tcp[p]"]) == episode["max_abs_error"].get("ee/panda_hand_tcp[p]", 0.0)
    with open_reader(out) as r, open_reader(src) as original:
        assert r.meta.control_mode == mode and r.meta.action_space["shape"] == [7 if "ee" in mode else 8]
        assert r.meta.provenance["source"] == str(src.resolve())
        assert r.meta.provenance["conversion"]["control_mode"] == ["pd_joint_pos", mode]
        for m in r.episodes:
            assert m.provenance.source_episode == m.index and m.provenance.verdict in ("exact", "within_tolerance")
            assert r.read_episode(m.index).length == original.read_episode(m.index).length
    # the converted file is a trajectory of its own: replayed in its control mode, it is reproduced exactly
    assert main(["replay", str(out), "-q"]) == 0
    assert "all verified" in capsys.readouterr().out


class WrongGain:
    """A deliberately bad conversion: the right converter, but from step `start` on its arm action (all but the
    gripper, the last dimension) is scaled by `gain`."""

    def __init__(self, inner, start: int, gain: float) -> None:
        self.inner, self.start, self.gain, self.target_mode = inner, start, gain, inner.target_mode
        self.t = 0

    def bind(self, unwrapped) -> None:
        self.inner.bind(unwrapped)
        self.t = 0

    def __call__(self, action):
        converted = self.inner(action)
        if self.t >= self.start:
            converted = ConvertedAction(np.r_[converted.action[:-1] * self.gain, converted.action[-1:]],
                                        converted.clipped, converted.wanted)
        self.t += 1
        return converted

    def commanded(self):
        return self.inner.commanded()


def _fastest_step(path: Path) -> int:
    """The step at which the recorded robot moves most (its joint positions change most)."""
    with open_reader(path) as r:
        qpos = r.read_episode(0).env_states["articulations/panda"][:, 13:20]
    return int(np.abs(np.diff(qpos, axis=0)).max(axis=1)[1:].argmax()) + 1


@pytest.mark.parametrize("mode", MODES)
def test_a_wrong_gain_is_caught_at_the_step_it_starts(demos, mode, tmp_path):
    src = demos("PickCube-v1")
    start = _fastest_step(src)

    def bad(*args):
        return WrongGain(converter_for(*args), start, 0.5)

    report = convert_recording(src, tmp_path / "bad.h5", control_mode=mode, episodes=[0], converter=bad)
    [episode] = report.episodes
    assert episode.verdict == "diverged" and not report.ok
    assert episode.first_divergence.step == start and episode.first_divergence.key.startswith("command/panda_hand_tcp")
    before = episode.per_step[episode.first_divergence.key][:start]  # the steps before the bad action
    assert max(before) <= report.tolerances["cmd_pos" if episode.first_divergence.key.endswith("[p]") else "cmd_rot"]


class AlwaysClipped:
    """The right converter, but every converted action reported clipped (the target mode reaching no step's
    target)."""

    def __init__(self, inner) -> None:
        self.inner, self.target_mode = inner, inner.target_mode

    def bind(self, unwrapped) -> None:
        self.inner.bind(unwrapped)

    def __call__(self, action):
        converted = self.inner(action)
        return ConvertedAction(converted.action, True, converted.wanted)

    def commanded(self):
        return self.inner.commanded()


def test_an_episode_clipped_at_every_step_has_its_commands_shown_unjudged(demos, tmp_path):
    src = demos("PickCube-v1")
    report = convert_recording(src, tmp_path / "out.h5", control_mode="pd_joint_delta_pos", episodes=[0],
                               converter=lambda *args: AlwaysClipped(converter_for(*args)))
    [episode] = report.episodes
    assert episode.checked == ["end-effector pose", "object poses", "success"]
    assert not any(key.startswith("command/") for key in episode.max_abs_error)
    [row] = [line for line in report.summary().splitlines() if line.lstrip().startswith("0 ")]
    assert row.split()[3:5] == ["-", "-"], row  # episode, steps, verdict, then the two command columns


def test_by_default_only_verified_episodes_are_written_and_the_run_still_fails(demos, tmp_path, capsys):
    src = demos("PickCube-v1")

    def bad_first_episode(*args):
        return _BadEpisode(converter_for(*args))

    report = convert_recording(src, tmp_path / "kept.h5", control_mode="pd_joint_delta_pos",
                               converter=bad_first_episode)
    assert [e.verdict for e in report.episodes][0] == "diverged" and report.episodes[1].ok
    assert report.written == [1] and report.dropped == {0: "not verified (diverged)"} and not report.ok
    assert report.to_json()["left_out"] == 1
    assert report.summary().endswith("1 of 2 episode(s) verified; 1 written to "
                                     f"{tmp_path / 'kept.h5'}; 1 left out by --keep (1 not verified; --keep all "
                                     "writes them)")
    with open_reader(tmp_path / "kept.h5") as r:
        assert [m.index for m in r.episodes] == [1]
        assert r.meta.provenance["filters"]["keep"] == ["verified"]
    capsys.readouterr()
    assert main(["inspect", str(tmp_path / "kept.h5")]) == 0
    assert (f"made by    convert of {src.resolve()} (episodes 0, 1): control_mode pd_joint_pos -> pd_joint_delta_pos; "
            "kept: verified") in capsys.readouterr().out


def test_failed_conversions_are_left_out_unless_keep_all(tmp_path, capsys):
    """Random pd_joint_pos actions jump further than pd_ee_delta_pose reaches in a step: no episode verifies, none
    is written (exit 1); `--keep all` writes them all and the exit status is still 1."""
    src, out, every = tmp_path / "rand.h5", tmp_path / "out.h5", tmp_path / "all.h5"
    assert main(["record", "PickCube-v1", "-o", str(src), "-n", "2", "--max-steps", "15", "--control-mode",
                 "pd_joint_pos", "--seed", "3", "-q"]) == 0
    capsys.readouterr()
    assert main(["convert", str(src), str(out), "--control-mode", "pd_ee_delta_pose", "-q"]) == 1
    printed = capsys.readouterr().out
    assert ("0 of 2 episode(s) verified; 0 written to " f"{out}; 2 left out by --keep (2 not verified; --keep all "
            "writes them)") in printed
    assert printed.count("not written: not verified") == 2 and not out.exists()
    assert main(["convert", str(src), str(every), "--control-mode", "pd_ee_delta_pose", "--keep", "all", "-q"]) == 1
    assert f"0 of 2 episode(s) verified; 2 written to {every}\n" in capsys.readouterr().out
    with open_reader(every) as r:
        assert [m.index for m in r.episodes] == [0, 1] and r.meta.provenance["filters"]["keep"] == ["all"]


class _BadEpisode:
    """Halves the arm action of the first episode it converts only."""

    def __init__(self, inner) -> None:
        self.inner, self.target_mode, self.episodes = inner, inner.target_mode, 0

    def bind(self, unwrapped) -> None:
        self.inner.bind(unwrapped)
        self.episodes += 1

    def __call__(self, action):
        converted = self.inner(action)
        if self.episodes == 1:
            return ConvertedAction(np.r_[converted.action[:-1] * 0.5, converted.action[-1:]], converted.clipped,
                                   converted.wanted)
        return converted

    def commanded(self):
        return self.inner.commanded()


def test_filters_and_exit_status_on_the_command_line(demos, tmp_path, capsys):
    src = demos("PickCube-v1")
    out = tmp_path / "one.h5"
    assert main(["convert", str(src), str(out), "--control-mode", "pd_joint_delta_pos", "--episodes", "1,0",
                 "--count", "1", "--keep", "success", "-q"]) in (0, 1)
    printed = capsys.readouterr().out
    with open_reader(src) as r:
        succeeded = bool(r.read_episode(1).success[-1])
    assert "1 episode(s)" in printed  # --count 1 of --episodes 1,0: episode 1 only
    if succeeded:
        with open_reader(out) as r:
            assert [m.index for m in r.episodes] == [1]
    else:
        assert "not written: no success at its last step" in printed


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--control-mode", "pd_joint_pos"], "--control-mode pd_joint_pos is the recording's own control mode"),
        (["--control-mode", "pd_ee_pose"], "cannot convert control mode pd_joint_pos to pd_ee_pose"),
        (["--keep", "verified"], "--keep apply to a conversion: add --obs-mode and/or --control-mode"),
        (["--obs-mode", "state", "--tol", "ee_pos=1"], "--tol sets the tracking tolerances of a control-mode conversion"),
        (["--control-mode", "pd_joint_delta_pos", "--keep", "fast"], "expected any of verified, success, not_truncated, all"),
        (["--control-mode", "pd_joint_delta_pos", "--keep", "all,success"],
         "--keep all,success: all writes every converted episode; give it alone"),
    ],
    ids=["same-mode", "unsupported-pair", "filter-without-conversion", "tol-without-control", "bad-keep", "keep-all-and"],
)
def test_bad_conversions_are_one_line_exit_2(demos, tmp_path, capsys, args, message):
    src = demos("PickCube-v1")
    capsys.readouterr()  # what recording the demos printed (ManiSkill's render-device warning)
    try:
        code = main(["convert", str(src), str(tmp_path / "out.h5"), "-q", *args])
    except SystemExit as e:  # argparse's own refusal of a bad value
        code = e.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "out.h5").exists()


def test_a_robot_without_an_arm_and_the_gpu_sim_are_refused(tmp_path, capsys):
    valve = record_maniskill(tmp_path, "RotateValveLevel0-v1", name="valve", episodes=1, steps=3, path="smooth")
    capsys.readouterr()  # ManiSkill's own warnings while recording
    assert main(["convert", str(valve), str(tmp_path / "out.h5"), "--control-mode", "pd_joint_delta_pos", "-q"]) == 2
    ours = [line for line in capsys.readouterr().err.splitlines() if line.startswith("simreel")]  # not ManiSkill's logs
    assert len(ours) == 1 and "robot dclaw has no 'arm' controller" in ours[0], ours
    sidecar = valve.with_suffix(".json")
    doc = json.loads(sidecar.read_text())
    doc["env_info"]["env_kwargs"].update(sim_backend="physx_cuda", num_envs=4)
    sidecar.write_text(json.dumps(doc))
    assert main(["convert", str(valve), str(tmp_path / "out.h5"), "--control-mode", "pd_joint_delta_pos", "-q"]) == 2
    assert "control-mode conversion runs on the CPU sim only" in capsys.readouterr().err


@pytest.mark.slow
def test_a_demo_the_target_mode_cannot_follow_is_reported(tmp_path):
    """Path 101 pushes PegInsertionSide's arm against the scene: the recorded joint targets run 0.1 rad ahead of the
    joints, out of one pd_joint_delta_pos step's reach. The conversion says so and fails the episode."""
    src = record_maniskill(tmp_path, "PegInsertionSide-v1", name="peg", episodes=2, steps=STEPS, path="smooth",
                           path_seed=100)
    report = convert_recording(src, tmp_path / "out.h5", control_mode="pd_joint_delta_pos", episodes=[1])
    [episode] = report.episodes
    assert episode.verdict == "diverged" and not report.ok
    assert any("action was clipped to its limits" in note for note in episode.notes)
    assert episode.first_divergence.key.startswith(("ee/", "env_states/"))  # the trajectory, not the commands


@pytest.mark.slow
def test_workers_convert_the_same_episodes_to_the_same_verdicts(demos, tmp_path):
    src = demos("PickCube-v1")
    one = convert_recording(src, tmp_path / "one.h5", control_mode="pd_ee_delta_pose")
    two = convert_recording(src, tmp_path / "two.h5", control_mode="pd_ee_delta_pose", workers=2)
    assert [e.index for e in two.episodes] == [e.index for e in one.episodes] and two.ok
    with open_reader(tmp_path / "two.h5") as r:
        assert [m.index for m in r.episodes] == [0, 1]


def test_a_conversion_to_joint_velocities_is_checked_like_any_other(demos, tmp_path, capsys):
    """pd_joint_pos -> pd_joint_vel (ManiSkill converts it; simreel refused it): a velocity controller follows the
    joint path less closely, which the check measures and says; with the tolerance loosened it verifies, and the
    converted file replays exact in its own mode."""
    src = demos("PickCube-v1")
    assert main(["convert", str(src), str(tmp_path / "strict.h5"), "--control-mode", "pd_joint_vel", "-q"]) == 1
    assert "0 of 2 episode(s) verified" in capsys.readouterr().out
    out = tmp_path / "vel.h5"
    assert main(["convert", str(src), str(out), "--control-mode", "pd_joint_vel", "--tol", "ee_pos=0.02",
                 "--tol", "obj_pos=0.005", "-q"]) == 0
    assert "2 of 2 episode(s) verified; 2 written" in capsys.readouterr().out
    with open_reader(out) as r:
        assert r.meta.control_mode == "pd_joint_vel" and r.meta.action_space["shape"] == [8]
    assert main(["replay", str(out), "-q"]) == 0


@pytest.mark.parametrize("mode", ["pd_ee_pose", "pd_joint_pos_vel"])
def test_a_mode_simreel_does_not_convert_to_is_refused_in_one_line(demos, tmp_path, capsys, mode):
    assert main(["convert", str(demos("PickCube-v1")), str(tmp_path / "x.h5"), "--control-mode", mode, "-q"]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(f"simreel convert: error: cannot convert control mode pd_joint_pos to {mode}: simreel "
                           "converts pd_joint_pos -> pd_joint_delta_pos, pd_joint_target_delta_pos, pd_joint_vel, "
                           "pd_ee_delta_pos, pd_ee_delta_pose, pd_ee_target_delta_pos, pd_ee_target_delta_pose;")
    assert list(tmp_path.iterdir()) == []
