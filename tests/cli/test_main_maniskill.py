"""Every command on ManiSkill's own trajectory files (RecordEpisode and replay_trajectory outputs of four tasks,
made here with ManiSkill's tools): inspect, replay (verified exact), view --save, convert both ways; an altered
action is found at its step; what simreel converts back is read by ManiSkill's loader and replay_trajectory."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from support.maniskill_files import record_maniskill, replay_maniskill

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
    from simreel.compare import Tolerances
    from simreel.replay.engine import EpisodeReplayer
    from simreel.replay.workers import ReplayJob

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
