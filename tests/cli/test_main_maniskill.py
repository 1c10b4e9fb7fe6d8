"""Every command on ManiSkill's own trajectory files (RecordEpisode and replay_trajectory outputs of four tasks,
made here with ManiSkill's tools): inspect, replay (verified exact), view --save, convert both ways; an altered
action is found at its step; what simreel converts back is read by ManiSkill's loader and replay_trajectory."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from support.maniskill_files import copy_recording, edit_sidecar, record_maniskill, replay_maniskill

from simreel.cli.main import main
from simreel.formats import open_reader

TASKS = [
    "PickCube-v1",
    pytest.param("StackCube-v1", marks=pytest.mark.slow),
    pytest.param("PegInsertionSide-v1", marks=pytest.mark.slow),  # merged views in the registry
    pytest.param("RotateValveLevel0-v1", marks=pytest.mark.slow),  # an articulation task (valve, D'Claw)
]


def _replay_report(path: Path, tmp_path: Path, capsys, *extra: str) -> dict:
    report = tmp_path / f"{path.name}.report.json"
    assert main(["replay", str(path), "-q", "--report", str(report), *extra]) == 0, capsys.readouterr()
    return json.loads(report.read_text())


def _every_command(path: Path, tmp_path: Path, capsys) -> None:
    assert main(["inspect", str(path)]) == 0
    report = _replay_report(path, tmp_path, capsys)
    assert [e["verdict"] for e in report["episodes"]] == ["exact"] * len(report["episodes"]), report
    assert "contact forces not compared: the file holds none" in report["files"][0]["limits"]
    rrd = tmp_path / f"{path.name}.rrd"
    assert main(["view", str(path), "--save", str(rrd), "--geometry", "collision"]) == 0 and rrd.stat().st_size
    replayed = tmp_path / f"{path.name}.replayed.h5"
    assert main(["replay", str(path), "-q", "--episodes", "1", "-o", str(replayed)]) == 0
    compared = tmp_path / f"{path.name}.compare.rrd"
    assert main(["view", str(path), "--episode", "1", "--compare", str(replayed), "--save", str(compared),
                 "--geometry", "collision"]) == 0
    assert "replay exact: no value leaves its tolerance" in capsys.readouterr().out
    for suffix in (".mcap", ".h5"):
        out = tmp_path / f"{path.name}.converted{suffix}"
        assert main(["convert", str(path), str(out), "-q"]) == 0
        again = _replay_report(out, tmp_path, capsys)
        assert all(e["verdict"] == "exact" for e in again["episodes"]), again


@pytest.mark.parametrize("env_id", TASKS)
def test_every_command_works_on_recordepisode_and_replay_trajectory_files(env_id, maniskill_env, tmp_path, capsys):
    recorded = record_maniskill(tmp_path, env_id, name="demos", episodes=2, steps=12)
    _every_command(recorded, tmp_path, capsys)
    converted = replay_maniskill(recorded, maniskill_env, "-o", "state")  # pd_joint_pos demos -> state obs
    _every_command(converted, tmp_path, capsys)


def test_every_replay_mode_on_a_maniskill_file(tmp_path, capsys):
    path = record_maniskill(tmp_path, "PickCube-v1", name="demos", episodes=2, steps=12, obs_mode="state")
    for extra, verdicts in ((["--mode", "states"], {"exact", "within_tolerance"}),
                            (["--mode", "step"], {"exact", "within_tolerance"}),
                            (["--resync", "4"], {"exact", "within_tolerance"}),
                            (["--workers", "2"], {"exact"})):
        report = _replay_report(path, tmp_path, capsys, *extra, "--overwrite")
        assert {e["verdict"] for e in report["episodes"]} <= verdicts, (extra, report)
        assert report["episodes"][0]["checked"] == ["env_states", "obs", "rewards", "terminated", "truncated",
                                                    "success"]


def test_one_step_noise_in_observed_joint_velocities_is_judged_as_the_states_are(tmp_path, capsys):
    """A grasp: one step from a restored state moves the arm's joint velocities by ~1e-2, well within step mode's qvel
    tolerance; the state observation holds those velocities, and is not called diverged for them."""
    path = record_maniskill(tmp_path, "PickCube-v1", name="grasp", episodes=1, steps=45, path="pick", path_seed=102,
                            obs_mode="state")
    for extra in (["--mode", "step"], ["--resync", "5"]):
        report = _replay_report(path, tmp_path, capsys, *extra, "--overwrite")
        [episode] = report["episodes"]
        assert episode["verdict"] == "within_tolerance" and episode["max_abs_error"]["obs/state"] > 1e-2, extra


def test_an_altered_action_is_found_at_its_step(tmp_path, capsys):
    path = record_maniskill(tmp_path, "PickCube-v1", name="demos", episodes=2, steps=15)
    with h5py.File(path, "a") as f:
        f["traj_1/actions"][7, :3] += 0.2  # three arm joint targets of step 7
    assert main(["replay", str(path), "-q", "--report", str(tmp_path / "r.json")]) == 1
    report = json.loads((tmp_path / "r.json").read_text())
    first, altered = report["episodes"][0], report["episodes"][1]
    assert first["verdict"] == "exact" and altered["verdict"] == "diverged"
    assert altered["first_divergence"]["step"] == 7
    assert altered["first_divergence"]["key"] == "env_states/articulations/panda[qpos]"


def test_what_simreel_converts_back_is_read_by_maniskills_own_tools(maniskill_env, tmp_path):
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset

    original = record_maniskill(tmp_path, "PickCube-v1", name="demos", episodes=2, steps=10, obs_mode="state")
    out = tmp_path / "back.h5"
    assert main(["convert", str(original), str(out), "-q"]) == 0
    with open_reader(original) as r:
        episodes = [r.read_episode(m.index) for m in r.episodes]
    loaded = ManiSkillTrajectoryDataset(str(out))
    np.testing.assert_array_equal(loaded.obs, np.concatenate([ep.obs["state"][:-1] for ep in episodes]))
    np.testing.assert_array_equal(loaded.actions, np.concatenate([ep.actions for ep in episodes]))
    loaded.data.close()
    replayed = replay_maniskill(out, maniskill_env)
    with h5py.File(replayed, "r") as f:
        for ep in episodes:
            np.testing.assert_array_equal(f[f"traj_{ep.meta.index}/env_states/actors/cube"][()],
                                          ep.env_states["actors/cube"])


@pytest.mark.slow
def test_a_control_mode_conversion_by_replay_trajectory_verifies(maniskill_env, tmp_path, capsys):
    """replay_trajectory -c pd_ee_delta_pose writes a new trajectory (more steps); replayed, it is exact."""
    recorded = record_maniskill(tmp_path, "PickCube-v1", name="demos", episodes=1, steps=12)
    converted = replay_maniskill(recorded, maniskill_env, "-c", "pd_ee_delta_pose")
    shutil.copy(converted, tmp_path / "ee.h5")
    shutil.copy(converted.with_suffix(".json"), tmp_path / "ee.json")
    report = _replay_report(tmp_path / "ee.h5", tmp_path, capsys)
    with open_reader(tmp_path / "ee.h5") as r:
        assert r.meta.control_mode == "pd_ee_delta_pose" and r.episodes[0].length > 12
    assert report["episodes"][0]["verdict"] == "exact"


def test_a_file_without_rewards_replays_without_computing_them_and_minus_o_still_writes_real_ones(tmp_path, capsys):
    """Rewards nothing could check are not computed (reward_mode="none": ManiSkill's replay_trajectory computes
    them anyway); a replay written with -o computes them, equal to what RecordEpisode recorded for the same run."""
    from simreel.model.components import Tolerances
    from simreel.replay.run.engine import EpisodeReplayer
    from simreel.replay.run.job import ReplayJob

    with_rewards = record_maniskill(tmp_path / "a", "PickCube-v1", episodes=2, steps=12)
    without = record_maniskill(tmp_path / "b", "PickCube-v1", episodes=2, steps=12, record_reward=False)
    with open_reader(without) as r:
        meta = r.meta
    assert "rewards" in meta.unknown
    job = ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions"))
    for output, mode in ((None, "none"), ("x.h5", "normalized_dense")):
        with EpisodeReplayer(meta, dataclasses.replace(job, output=output).replayer_options(meta)) as replayer:
            assert replayer.u.reward_mode == mode

    report = _replay_report(without, tmp_path, capsys)
    assert [e["verdict"] for e in report["episodes"]] == ["exact", "exact"]
    assert "rewards" not in report["episodes"][0]["checked"]
    replayed = tmp_path / "replayed.h5"
    assert main(["replay", str(without), "-q", "-o", str(replayed)]) == 0
    with open_reader(replayed) as out, h5py.File(with_rewards, "r") as f:
        for m in out.episodes:
            rewards = out.read_episode(m.index).rewards
            assert np.any(rewards != 0)
            np.testing.assert_array_equal(rewards, f[f"traj_{m.index}/rewards"][()])


# ------------------------------------------------------------------------------ altered and inconsistent files
@pytest.fixture(scope="module")
def altered_dir(tmp_path_factory) -> Path:
    """RecordEpisode files altered below: PickCube pd_joint_pos with nested observations, made with sim_backend
    "auto" (ManiSkill's default, which the sidecar records as given); with flat state observations; and one in
    pd_ee_delta_pose (7-number actions)."""
    folder = tmp_path_factory.mktemp("altered")
    record_maniskill(folder, "PickCube-v1", name="auto", episodes=2, steps=10, obs_mode="state_dict",
                     env_kwargs={"sim_backend": "auto"})
    record_maniskill(folder, "PickCube-v1", name="flat", episodes=1, steps=5, obs_mode="state")
    record_maniskill(folder, "PickCube-v1", name="ee", episodes=1, steps=5, control_mode="pd_ee_delta_pose")
    return folder


def _replay(path: Path, tmp_path: Path, status: int, *extra: str) -> dict:
    report = tmp_path / "report.json"
    assert main(["replay", str(path), "-q", "--report", str(report), "--overwrite", *extra]) == status
    return json.loads(report.read_text())


def test_sim_backend_auto_is_the_cpu_sim_it_resolves_to_not_a_build_difference(altered_dir, tmp_path, capsys):
    """A divergence (a reward altered) is explained without blaming the build: "auto" with one env is physx_cpu."""
    path = copy_recording(altered_dir, "auto", tmp_path)
    with h5py.File(path, "a") as f:
        assert json.loads(path.with_suffix(".json").read_text())["env_info"]["env_kwargs"]["sim_backend"] == "auto"
        f["traj_1/rewards"][5] += 0.01
    report = _replay(path, tmp_path, 1)
    assert [e["verdict"] for e in report["episodes"]] == ["exact", "diverged"]
    assert "sim backend" not in capsys.readouterr().err and "sim backend" not in json.dumps(report["episodes"][1])


def test_a_group_the_sidecar_does_not_list_is_named_by_replay(altered_dir, tmp_path, capsys):
    """A group a killed RecordEpisode left unlisted is not replayed (as ManiSkill's tools skip it): the replay says
    so, on stderr and in its report, not only `inspect`."""
    path = copy_recording(altered_dir, "auto", tmp_path)
    with h5py.File(path, "a") as f:
        f.copy("traj_0", "traj_7")
    report = _replay(path, tmp_path, 0)
    said = "1 group(s) the sidecar does not list (traj_7) are skipped, as ManiSkill's tools skip them"
    assert f"simreel replay: warning: {said}" in capsys.readouterr().err
    assert said in report["files"][0]["warnings"]


def test_a_sidecar_success_the_data_does_not_end_with_is_noted(altered_dir, tmp_path):
    path = copy_recording(altered_dir, "auto", tmp_path)
    with h5py.File(path, "r") as f:
        last = bool(f["traj_1/success"][-1])
    edit_sidecar(path, lambda d: d["episodes"][1].update(success=not last))
    report = _replay(path, tmp_path, 0)
    assert f"the sidecar says success {not last}, the file's success data ends {last} (inspect and filter --success go " \
           "by the sidecar, as ManiSkill's tools do)" in report["episodes"][1]["notes"]
    assert not any("sidecar says success" in n for n in report["episodes"][0]["notes"])


def test_a_nan_action_is_one_error_naming_its_episode_and_step(altered_dir, tmp_path):
    path = copy_recording(altered_dir, "auto", tmp_path)
    with h5py.File(path, "a") as f:
        f["traj_1/actions"][3, 0] = np.nan
    for mode in ("actions", "step"):
        report = _replay(path, tmp_path, 2, "--mode", mode)
        assert report["episodes"][0]["verdict"] in ("exact", "within_tolerance")
        assert report["episodes"][1]["error"] == ("episode 1: the recorded action of step 3 holds NaN, which "
                                                  "ManiSkill's CPU sim refuses to step (on it, no recorder stepped it: "
                                                  "the file was altered or damaged)")


@pytest.mark.parametrize(
    ("edit", "why"),
    [
        (("auto", lambda d: [e.update(control_mode="pd_ee_delta_pose") for e in [d["env_info"]["env_kwargs"],
                                                                                 *d["episodes"]]]),
         "PickCube-v1: the recorded actions have shape (8,) a step, but its control mode, pd_ee_delta_pose, takes "
         "actions of shape (7,): the recording must name the control mode that recorded them"),
        (("ee", lambda d: [e.pop("control_mode") for e in [d["env_info"]["env_kwargs"], *d["episodes"]]]),
         "PickCube-v1: the recorded actions have shape (7,) a step, but it names no control mode, and PickCube-v1's "
         "default, pd_joint_delta_pos, takes actions of shape (8,): the recording must name the control mode that "
         "recorded them"),
    ],
    ids=["another-control-mode", "no-control-mode"],
)
def test_actions_that_do_not_fit_the_named_control_mode_are_one_line(altered_dir, tmp_path, capsys, edit, why):
    """(file, sidecar change): the sidecar then names a control mode whose actions have another shape, or none."""
    name, change = edit
    path = copy_recording(altered_dir, name, tmp_path)
    edit_sidecar(path, change)
    assert main(["replay", str(path), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and why in err, err


def test_observation_keys_the_replay_lacks_or_shapes_otherwise_are_named_not_compared(altered_dir, tmp_path):
    path = copy_recording(altered_dir, "auto", tmp_path)
    with h5py.File(path, "a") as f:
        for g in ("traj_0", "traj_1"):
            f.move(f"{g}/obs/extra/tcp_pose", f"{g}/obs/extra/tcp_pose_renamed")
            qvel = f[f"{g}/obs/agent/qvel"][()]
            del f[f"{g}/obs/agent/qvel"]
            f[f"{g}/obs/agent/qvel"] = qvel[:, :8] + 1.0
    report = _replay(path, tmp_path, 0)
    for episode in report["episodes"]:
        assert episode["verdict"] == "exact" and "obs" in episode["checked"]
        assert {"obs/agent/qvel not compared: (8,) a row in the file, (9,) in the replay",
                "obs/extra/tcp_pose_renamed not compared: the replay's observation has no such key"} <= set(
            episode["limits"]), episode["limits"]


def test_a_flat_observation_under_a_dict_obs_mode_is_named_not_compared(altered_dir, tmp_path):
    """A sidecar naming obs_mode state_dict over a file holding one flat `obs` array: nothing of it is compared."""
    path = copy_recording(altered_dir, "flat", tmp_path)
    edit_sidecar(path, lambda d: d["env_info"]["env_kwargs"].update(obs_mode="state_dict"))
    episode = _replay(path, tmp_path, 0)["episodes"][0]
    assert "obs" not in episode["checked"]
    assert "obs/state_dict not compared: the replay's observation has no such key" in episode["limits"]


@pytest.mark.parametrize(
    ("options", "held"),
    [({"record_reward": False}, "no env_states, observations or rewards"),
     ({"env_kwargs": {"reward_mode": "sparse"}}, "no env_states or observations, and its rewards are sparse")],
    ids=["no-rewards", "sparse-rewards"],
)
def test_a_file_that_holds_only_flags_is_refused_never_called_exact(tmp_path, capsys, options, held):
    """RecordEpisode(record_env_state=False) with obs_mode "none" and no rewards (or sparse ones: success - fail again)
    leaves a replay only the flags to compare, all False here: actions zeroed still replayed "exact" before. One line,
    exit 2; in a dataset run the file is an error and the other files replay."""
    path = record_maniskill(tmp_path / "data", "PickCube-v1", name="flags", episodes=1, steps=4, obs_mode="none",
                            record_env_state=False, **options)
    record_maniskill(tmp_path / "data", "PickCube-v1", name="full", episodes=1, steps=4)
    with h5py.File(path, "a") as f:
        f["traj_0/actions"][...] = 0.0
    capsys.readouterr()
    assert main(["replay", str(path), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}: holds {held} (recorded without them): a replay could compare only its " \
        "flags (terminated, truncated, success), which do not tell whether the trajectory reproduced" in err, err
    report = _replay(tmp_path / "data", tmp_path, 2)
    assert [(Path(e["file"]).name, e["verdict"]) for e in report["episodes"]] == [("full.h5", "exact")], report


def test_a_sidecar_naming_an_unknown_robot_is_one_line(altered_dir, tmp_path):
    """Regression: ManiSkill's WARNING ("nobot is not in the task's list of supported robots") came before the
    run's own line; a build that fails drops the log lines ManiSkill wrote while building."""
    path = copy_recording(altered_dir, "flat", tmp_path)
    edit_sidecar(path, lambda d: d["env_info"]["env_kwargs"].update(robot_uids="nobot"))
    done = subprocess.run([sys.executable, "-m", "simreel", "replay", str(path), "-q"], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == ("simreel replay: error: PickCube-v1: could not build the env: RuntimeError: Agent nobot not "
                           "found in the dict of registered agents. If the id is not a typo then make sure to apply "
                           "the @register_agent() decorator.\n")


def test_a_group_the_sidecar_does_not_list_is_named_by_convert_merge_and_filter(altered_dir, tmp_path, capsys):
    """`convert` (a copy or a verified conversion), `merge` and `filter` leave out a group the sidecar does not list, as ManiSkill's tools, `inspect` and
    `replay` do; they left it out without a word, and now say so as those do."""
    path = copy_recording(altered_dir, "auto", tmp_path)
    with h5py.File(path, "a") as f:
        f.copy("traj_0", "traj_7")
    said = "1 group(s) the sidecar does not list (traj_7) are skipped, as ManiSkill's tools skip them"
    assert main(["convert", str(path), str(tmp_path / "c.h5"), "-q"]) == 0
    assert f"simreel convert: warning: {path}: {said}\n" in capsys.readouterr().err
    assert main(["convert", str(path), str(tmp_path / "v.h5"), "--obs-mode", "state", "-q"]) == 0  # verified
    assert f"simreel convert: warning: {path}: {said}\n" in capsys.readouterr().err
    assert main(["merge", str(path), "-o", str(tmp_path / "m.h5"), "-q"]) == 0
    assert f"note: {path}: {said}\n" in capsys.readouterr().out
    assert main(["filter", str(path), "--episodes", "0", "-o", str(tmp_path / "f.h5"), "-q"]) == 0
    assert f"note: {path}: {said}\n" in capsys.readouterr().out
    for out, held in (("c.h5", 2), ("m.h5", 2), ("f.h5", 1)):
        with open_reader(tmp_path / out) as r:
            assert len(r.episodes) == held
