"""The step before an episode's reset (`simreel.replay.run.history.step_before`): observations at a reset read the contacts of the
step the scene ran last, so a replay that restores states re-runs the recorded episode's predecessor's last step
first. The recording: SimreelLiftCube-v1's scripted grasp and lift from seed 3, three episodes, with observations;
its is_grasped (obs/state[26]) is 1 at the resets of episodes 1 and 2 (the step before grasped the cube), 0 at
episode 0's (a scene just built)."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.model.components import Tolerances
from simreel.replay.run.job import ReplayJob
from simreel.replay.run.workers import ReplayWorker
from simreel.replay.run.worklist import WorkItem, env_key

IS_GRASPED = 26
"""SimreelLiftCube-v1's is_grasped in its flat state observation."""


@pytest.fixture(scope="module")
def lift(record):
    return record("SimreelLiftCube-v1", 3, 60, "--record-obs")


def _reset_grasped(path, episodes=range(3)) -> list[float]:
    with h5py.File(path, "r") as f:
        return [float(f[f"traj_{i}/obs"][0, IS_GRASPED]) for i in episodes]


def test_the_recording_is_grasped_at_the_resets_after_a_grasp(lift):
    assert _reset_grasped(lift) == [0.0, 1.0, 1.0]


@pytest.mark.parametrize("mode", ["states", "step"])
def test_an_episode_replayed_alone_renders_its_reset_after_the_step_before_it(lift, mode, tmp_path, capsys):
    """Regression: replayed alone (or first in its process) in a restoring mode, episode 2 read no contact at its
    reset: in mode states "diverged after reset: obs/state off by 1" (mode step's obs tolerance, 30, passed it)."""
    out = tmp_path / "replayed.h5"
    assert main(["replay", str(lift), "--mode", mode, "--episodes", "2", "-o", str(out), "-q"]) == 0
    assert "all verified" in capsys.readouterr().out
    assert _reset_grasped(out, [2]) == [1.0]


def _states_worker() -> ReplayWorker:
    return ReplayWorker(ReplayJob(mode="states", resync=None, tolerances=Tolerances.for_mode("states")))


def test_a_worker_renders_each_reset_after_the_step_its_recorder_ran_before_it(lift):
    """In any order: episode 0 after episode 2 needs a scene with no contact (its recorder's was just built)."""
    worker = _states_worker()
    try:
        with open_reader(lift) as reader:
            key = env_key(reader.meta)
        for index in (2, 0, 1, 2, 0):
            report = worker.run(WorkItem(key, str(lift), index)).report
            assert report.verdict == "within_tolerance", (index, report.first_divergence)
            assert report.limits == []
    finally:
        worker.close()


def test_a_worker_re_runs_the_step_before_only_where_its_scene_did_not_run_it_last(lift, monkeypatch):
    worker = _states_worker()
    re_run: list[int | None] = []
    try:
        with open_reader(lift) as reader:
            key = env_key(reader.meta)
        worker.prepare(WorkItem(key, str(lift), 0))
        replayer = worker._replayer
        real = replayer.rerun_step_before

        def spy(before):  # None: nothing to re-run
            if before is not None:
                re_run.append(before.episode and before.episode.index)
            real(before)

        monkeypatch.setattr(replayer, "rerun_step_before", spy)
        for index in (0, 1, 2, 1, 0):
            assert worker.run(WorkItem(key, str(lift), index)).report.verdict == "within_tolerance"
    finally:
        worker.close()
    assert re_run == [0, None]  # 1 after 2 (episode 0's last step); 0 after 1 (a scene just built: rebuilt)


def test_a_filtered_episode_without_the_one_before_it_says_its_reset_may_differ(lift, tmp_path):
    out, report = tmp_path / "two.h5", tmp_path / "r.json"
    assert main(["filter", str(lift), "-o", str(out), "--episodes", "2", "-q"]) == 0
    assert main(["replay", str(out), "--mode", "states", "--report", str(report), "-q"]) == 1
    (episode,) = json.loads(report.read_text())["episodes"]
    assert episode["verdict"] == "diverged" and episode["first_divergence"]["step"] == 0
    assert ("its observations at the reset read the contacts of whatever step its replaying scene ran last, not of "
            "the one its recorder's scene ran before it (the episode that ran before it is not in this file): "
            "contact-based values there (is_grasped) may differ") in episode["limits"]


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_re_render_gives_each_reset_the_recorded_contacts_in_any_process(lift, record, tmp_path, workers):
    """Regression: with --workers 2 the process that re-rendered episode 2 first wrote is_grasped 0 at its reset
    (one worker wrote 1, after episode 1): the output depended on the process, and its replay diverged."""
    without_obs = record("SimreelLiftCube-v1", 3, 60)
    out = tmp_path / "state.h5"
    assert main(["convert", str(without_obs), str(out), "--obs-mode", "state", "--workers", workers, "-q"]) == 0
    assert _reset_grasped(out) == [0.0, 1.0, 1.0]
    with h5py.File(out, "r") as rendered, h5py.File(lift, "r") as recorded:
        for i in range(3):
            np.testing.assert_allclose(rendered[f"traj_{i}/obs"][()], recorded[f"traj_{i}/obs"][()], rtol=0, atol=1e-6)
    assert main(["replay", str(out), "-q"]) == 0


def test_a_re_render_in_the_recorded_mode_checks_the_observations(lift, tmp_path, capsys):
    out = tmp_path / "again.h5"
    assert main(["convert", str(lift), str(out), "--obs-mode", "state", "--episodes", "2", "-q"]) == 0
    assert "the rendered observations against the recorded ones" in capsys.readouterr().out
    assert _reset_grasped(out, [2]) == [1.0]


def test_a_re_render_whose_observations_are_not_the_recorded_ones_is_not_verified(lift, tmp_path):
    altered, out, report = tmp_path / "altered.h5", tmp_path / "out.h5", tmp_path / "r.json"
    shutil.copy(lift, altered)
    with h5py.File(altered, "r+") as f:
        f["traj_1/obs"][5, 0] += 0.5
    assert main(["convert", str(altered), str(out), "--obs-mode", "state", "--report", str(report), "-q"]) == 1
    episodes = json.loads(report.read_text())["episodes"]
    assert [e["verdict"] for e in episodes] == ["within_tolerance", "diverged", "within_tolerance"]
    assert episodes[1]["first_divergence"]["step"] == 4 and episodes[1]["first_divergence"]["key"] == "obs/state"


def test_a_file_of_another_state_layout_is_one_clear_error_also_when_the_step_before_runs_first(lift, tmp_path,
                                                                                                 capsys):
    """Regression: the step before an episode was restored before the rebuilt env's layout was checked: a KeyError,
    "internal error" (exit 3), where the episode alone gets the one line."""
    renamed = tmp_path / "renamed.h5"
    shutil.copy(lift, renamed)
    with h5py.File(renamed, "r+") as f:
        meta = json.loads(f.attrs["simreel_meta"])
        meta["state_layout"] = {k.replace("actors/cube", "actors/cube2"): v for k, v in meta["state_layout"].items()}
        f.attrs["simreel_meta"] = json.dumps(meta)
        for name in (k for k in f if k.startswith("traj_")):
            f[name]["env_states/actors"].move("cube", "cube2")
    assert main(["replay", str(renamed), "--mode", "states", "--episodes", "2", "-q"]) == 2
    assert "has another state layout than the recording" in capsys.readouterr().err


def test_what_the_step_befores_reset_finds_of_the_scene_reaches_the_episodes_report(lift, tmp_path):
    """Regression (review): the reset of the step before builds the scene, so the replayer found there that a contact
    channel's body is missing, and the episode's own reset no longer said so: its limits lacked it."""
    ghost = tmp_path / "ghost.h5"
    shutil.copy(lift, ghost)
    with h5py.File(ghost, "r+") as f:
        meta = json.loads(f.attrs["simreel_meta"])
        meta["contact_channels"][0]["bodies"] = ["ghost"]
        f.attrs["simreel_meta"] = json.dumps(meta)
    report = tmp_path / "r.json"
    main(["replay", str(ghost), "--mode", "states", "--episodes", "2", "--report", str(report), "-q"])
    (episode,) = json.loads(report.read_text())["episodes"]
    assert "contacts not compared: the rebuilt scene has no body 'ghost'" in episode["limits"]
