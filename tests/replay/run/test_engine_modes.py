"""Replay-and-verify on real ManiSkill envs (CPU sim, state only): every mode, divergences, resets, -o output."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from simreel.cli.main import main
from simreel.formats import open_reader, open_writer
from simreel.model.components import Tolerances
from simreel.replay.run.engine import EpisodeReplayer
from simreel.replay.run.verify import verify_recording
from simreel.verdicts.compare import compare_episode

SIMREEL_TASKS = ("SimreelLiftCube-v1", "SimreelLiftCubeLeaky-v1", "SimreelHeteroPick-v1", "SimreelHeteroDrawer-v1")
BUILTINS = ("PickCube-v1", "StackCube-v1", "PegInsertionSide-v1", "RotateValveLevel0-v1", "PushCube-v1")


def _perturb(src: Path, dst: Path, *, episode: int, step: int) -> None:
    """Copy a recording, flipping the first action component of one step (same bounds, very different action)."""
    with open_reader(src) as reader, open_writer(dst, reader.meta) as writer:
        for m in reader.episodes:
            ep = reader.read_episode(m.index)
            if m.index == episode:
                ep.actions = ep.actions.copy()
                ep.actions[step, 0] = 0.9 if ep.actions[step, 0] < 0 else -0.9
            writer.write_episode(ep)


@pytest.mark.parametrize("env_id", BUILTINS + SIMREEL_TASKS)
def test_action_replay_of_fresh_recordings_verifies(record, env_id):
    report = verify_recording(record(env_id, 2, 20))
    assert report.ok, report.summary()
    assert [e.verdict for e in report.episodes] == ["exact", "exact"], report.summary()
    assert report.warnings == []  # same machine, same versions


def test_time_limit_and_every_flag_are_reproduced(record):
    path = record("PickCube-v1", 1, 50)  # PickCube's limit is 50 steps: the last step is truncated
    with open_reader(path) as r:
        assert r.read_episode(0).truncated[-1]
    for mode in ("actions", "states", "step"):
        report = verify_recording(path, mode=mode)
        assert report.ok, report.summary()
        assert report.episodes[0].max_abs_error["truncated"] == 0.0


def test_perturbed_action_is_reported_at_its_step_on_the_robot(record, tmp_path, capsys):
    bad = tmp_path / "perturbed.h5"
    _perturb(record("PickCube-v1", 2, 20), bad, episode=1, step=7)
    report_path = tmp_path / "report.json"
    assert main(["replay", str(bad), "--report", str(report_path), "-q"]) == 1
    out = capsys.readouterr().out
    assert "diverged" in out and "step 7: env_states/articulations/panda[qpos]" in out
    doc = json.loads(report_path.read_text())
    assert doc["ok"] is False
    first, second = doc["episodes"]
    assert (first["index"], first["verdict"], first["first_divergence"]) == (0, "exact", None)
    assert second["verdict"] == "diverged"
    assert second["first_divergence"]["step"] == 7
    assert second["first_divergence"]["key"] == "env_states/articulations/panda[qpos]"
    assert second["first_divergence"]["error"] > 1e-3
    assert second["max_abs_error"]["env_states/articulations/panda[qpos]"] >= second["first_divergence"]["error"]
    assert all(isinstance(v, float) for v in second["max_abs_error"].values())


def test_resync_contains_a_divergence(record, tmp_path):
    bad = tmp_path / "perturbed.h5"
    _perturb(record("PickCube-v1", 2, 20), bad, episode=0, step=7)
    with open_reader(bad) as r:
        ep = r.read_episode(0)
        with EpisodeReplayer(r.meta) as replayer:
            plain = replayer.replay(ep, mode="actions")
            resynced = replayer.replay(ep, mode="actions", resync=5)
    key = "env_states/articulations/panda[qpos]"
    tol = Tolerances.for_mode("resync")
    err_plain = compare_episode(ep, plain.episode, tol).errors[key]
    cmp = compare_episode(ep, resynced.episode, tol)
    assert cmp.first_divergence.step == 7 and cmp.first_divergence.key == key
    # rows 11.. are the outcomes of actions 10..: the restore at step 10 undid the damage; without it, it stays
    assert cmp.errors[key][11:].max() < tol["qpos"] < err_plain[11:].max()
    assert verify_recording(bad, resync=5, episodes=[1]).ok


def test_step_mode_reports_per_key_one_step_errors(record, capsys):
    path = record("StackCube-v1", 2, 20)
    assert main(["replay", str(path), "--mode", "step", "-q"]) == 0
    out = capsys.readouterr().out
    assert "largest one-step errors per key" in out
    report = verify_recording(path, mode="step")
    ep = report.episodes[0]
    assert ep.verdict == "within_tolerance"
    assert {"env_states/actors/cubeA[p]", "env_states/actors/cubeB[q]", "rewards", "success"} <= set(ep.max_abs_error)
    assert any(k.startswith("env_states/articulations/") and k.endswith("[qpos]") for k in ep.max_abs_error)
    assert 0 < ep.max_abs_error["env_states/actors/cubeA[p]"] < 1e-4  # the restore noise, measured ~1e-6


def test_states_mode_recomputes_and_writes_a_replayed_recording(record, tmp_path):
    path = record("SimreelLiftCube-v1", 2, 20, "--record-obs")
    out = tmp_path / "replayed.h5"
    command = f"simreel replay {path} --mode states -o {out}"
    report = verify_recording(path, mode="states", output=out, command=command)
    assert report.ok, report.summary()
    assert report.episodes[0].max_abs_error["env_states/goal_height"] == 0.0  # custom state restored
    assert any(k.startswith("obs/") for k in report.episodes[0].max_abs_error)  # observations recomputed, compared
    with open_reader(path) as a, open_reader(out) as b:
        assert [m.index for m in b.episodes] == [m.index for m in a.episodes]
        assert b.meta.state_layout == a.meta.state_layout and b.meta.obs_layout == a.meta.obs_layout
        ra, rb = a.read_episode(1), b.read_episode(1)
        np.testing.assert_allclose(rb.rewards, ra.rewards, atol=1e-5)
        np.testing.assert_array_equal(rb.success, ra.success)
        assert set(rb.obs) == set(ra.obs)
        assert b.meta.command == command  # the replay's provenance, not the recording's
    assert verify_recording(out).ok  # the replayed file is itself a replayable recording


def test_heterogeneous_scenes_are_rebuilt_for_any_episode_order(record, tmp_path):
    """reconfiguration_freq=2: episodes 0 (gym.make's scene), 1 (new scene, seed 4), 2 (scene of 1), 3 (new)."""
    path = record("SimreelHeteroPick-v1", 4, 12, "--env-kwargs", '{"reconfiguration_freq": 2}')
    with open_reader(path) as r:
        metas = r.episodes
        assert [(m.reconfigured, m.scene_seed) for m in metas] == [(False, None), (True, 4), (False, 4), (True, 6)]
        ep2 = r.read_episode(2)
        meta = r.meta
    report = verify_recording(path, episodes=[2, 0, 3, 1])
    assert [e.index for e in report.episodes] == [2, 0, 3, 1]
    assert [e.verdict for e in report.episodes] == ["exact"] * 4, report.summary()
    with EpisodeReplayer(meta) as replayer:  # alone, in gym.make's scene, episode 2 gets its own scene back first
        assert "rebuilt the scene with seed 4" in replayer.replay(ep2).notes
    # the test bed matters: the episode's seed alone, in gym.make's scene, gives another object
    with EpisodeReplayer(meta) as replayer:
        replayer.env.reset(seed=ep2.meta.seed)
        z = replayer.u.get_state_dict()["actors"]["object"][0, 2].item()
    assert abs(z - ep2.env_states["actors/object"][0, 2]) > 1e-4


def test_workers_replay_in_parallel_processes(record, tmp_path):
    path = record("PushCube-v1", 3, 10, "--env-kwargs", '{"reconfiguration_freq": 1}')  # three scene chains
    out = tmp_path / "replayed.h5"
    report = verify_recording(path, workers=2, output=out, report=str(tmp_path / "r.json"))
    assert [e.index for e in report.episodes] == [0, 1, 2]
    assert [e.verdict for e in report.episodes] == ["exact"] * 3
    log = [json.loads(line) for line in (tmp_path / "r.jsonl").read_text().splitlines()]
    assert len({e["worker"] for e in log if e["type"] == "episode"}) == 2
    with open_reader(out) as r:
        assert [m.index for m in r.episodes] == [0, 1, 2]


def test_report_json_shape(record, tmp_path):
    path = record("PickCube-v1", 2, 20)
    rp = tmp_path / "r.json"
    assert main(["replay", str(path), "--episodes", "1", "--report", str(rp), "-q", "--atol", "0.001",
                 "--tol", "contact=2"]) == 0
    doc = json.loads(rp.read_text())
    assert doc["ok"] is True and doc["mode"] == "actions"
    assert doc["tolerances"]["pos"] == 0.001 and doc["tolerances"]["contact"] == 2 and doc["tolerances"]["flag"] == 0
    (ep,) = doc["episodes"]
    assert {"index", "verdict", "first_divergence", "max_abs_error"} <= set(ep)
    assert ep["index"] == 1 and ep["verdict"] == "exact" and ep["first_divergence"] is None


def test_fingerprint_differences_are_warned_by_name(record, tmp_path, capsys):
    src = record("PickCube-v1", 2, 20)
    old = tmp_path / "old.h5"
    with open_reader(src) as r:
        meta = dataclasses.replace(r.meta, versions={**r.meta.versions, "mani_skill": "3.0.0b21", "sapien": "3.0.0"})
        with open_writer(old, meta) as w:
            w.write_episode(r.read_episode(0))
    assert main(["replay", str(old), "-q"]) == 0
    err = capsys.readouterr().err
    assert "simreel replay: warning: mani_skill: recorded 3.0.0b21, replaying 3.0.1" in err
    assert "simreel replay: warning: sapien: recorded 3.0.0, replaying 3.0.3" in err
