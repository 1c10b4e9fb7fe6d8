"""ManiSkill's own trajectory files, made here with ManiSkill's own tools (RecordEpisode, replay_trajectory):
read as they are, what they lack reported unknown, their quirks named, bad sidecars refused in one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from support.maniskill_files import record_maniskill, replay_maniskill

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.formats.maniskill.reader import ALWAYS_UNKNOWN, ManiskillReader


@pytest.fixture(scope="module")
def ms_dir(tmp_path_factory) -> Path:
    """PickCube-v1 demos the way ManiSkill's are published (pd_joint_pos, obs none, env states), with state
    observations, as nested state_dict observations, and without env states or rewards."""
    folder = tmp_path_factory.mktemp("maniskill")
    record_maniskill(folder, "PickCube-v1", name="demos", episodes=2, steps=15)
    record_maniskill(folder, "PickCube-v1", name="state", episodes=1, steps=10, obs_mode="state",
                     source_type="scripted", source_desc="joint-space random walks")
    record_maniskill(folder, "PickCube-v1", name="state_dict", episodes=1, steps=5, obs_mode="state_dict")
    record_maniskill(folder, "PickCube-v1", name="bare", episodes=1, steps=10, record_env_state=False,
                     record_reward=False)
    return folder


def test_a_recordepisode_file_is_read_as_it_is(ms_dir):
    path = ms_dir / "demos.h5"
    with open_reader(path) as r:
        assert isinstance(r, ManiskillReader) and r.kind == "ManiSkill trajectory file (JSON sidecar demos.json)"
        m = r.meta
        assert (m.env_id, m.obs_mode, m.control_mode, m.max_episode_steps, m.num_envs) == (
            "PickCube-v1", "none", "pd_joint_pos", 50, 1)
        assert m.action_space == {"shape": [8], "dtype": "float32"}
        assert set(m.state_layout) == {"actors/cube", "actors/goal_site", "actors/table-workspace",
                                       "articulations/panda"}
        assert m.unknown == [*ALWAYS_UNKNOWN, "fail"]  # PickCube reports no fail
        assert [(e.index, e.seed, e.length, e.reconfigured) for e in r.episodes] == [(0, 0, 15, None), (1, 1, 15, None)]
        ep = r.read_episode(1)
    with h5py.File(path, "r") as f:
        raw = f["traj_1"]
        np.testing.assert_array_equal(ep.actions, raw["actions"][()])
        np.testing.assert_array_equal(ep.rewards, raw["rewards"][()])
        np.testing.assert_array_equal(ep.success, raw["success"][()])
        np.testing.assert_array_equal(ep.env_states["articulations/panda"], raw["env_states/articulations/panda"][()])
    assert ep.fail is None and ep.contact_forces is None and ep.meta.notes == []


def test_observations_as_one_array_and_as_a_nested_dict(ms_dir):
    with open_reader(ms_dir / "state.h5") as r:
        assert list(r.meta.obs_layout) == ["state"] and r.meta.obs_layout["state"].shape == (42,)
        assert r.read_episode(0).obs["state"].shape == (11, 42)
        assert r.meta.source["source_type"] == "scripted" and r.meta.command == "joint-space random walks"
    with open_reader(ms_dir / "state_dict.h5") as r:
        assert {"agent/qpos", "extra/tcp_pose", "extra/is_grasped"} <= set(r.meta.obs_layout)
        assert r.read_episode(0).obs["extra/is_grasped"].dtype == bool


def test_what_a_file_does_not_hold_is_unknown_never_invented(ms_dir, capsys):
    with open_reader(ms_dir / "bare.h5") as r:
        assert {"rewards", "env_states"} <= set(r.meta.unknown) and r.meta.state_layout == {}
        ep = r.read_episode(0)
        assert ep.rewards is None and ep.env_states == {}
    assert main(["inspect", str(ms_dir / "bare.h5")]) == 0
    out = capsys.readouterr().out
    assert "unknown    not in the file: versions, sim_config" in out and "rewards" in out
    assert main(["replay", str(ms_dir / "bare.h5"), "-q"]) == 0
    out = capsys.readouterr().out
    assert "checked at every step: terminated, truncated, success" in out
    assert "limit: rewards not compared: the file holds none" in out and "limit: states not compared" in out
    assert main(["replay", str(ms_dir / "bare.h5"), "-q", "--mode", "step"]) == 2
    assert "--mode step restores recorded states" in capsys.readouterr().err


def _copy(ms_dir: Path, tmp_path: Path, name: str = "demos") -> Path:
    for suffix in (".h5", ".json"):
        shutil.copy(ms_dir / f"{name}{suffix}", tmp_path / f"{name}{suffix}")
    return tmp_path / f"{name}.h5"


def _edit_sidecar(path: Path, change) -> None:
    doc = json.loads(path.with_suffix(".json").read_text())
    change(doc)
    path.with_suffix(".json").write_text(json.dumps(doc))


@pytest.mark.parametrize(
    ("make_bad", "message"),
    [
        (lambda p: p.with_suffix(".json").unlink(),
         "a ManiSkill trajectory file (traj_N groups) without its JSON sidecar: {json} is missing"),
        (lambda p: p.with_suffix(".json").write_text("{not json"), "{json}: unreadable ManiSkill sidecar"),
        (lambda p: _edit_sidecar(p, lambda d: d.update(env_info=None)), "{json}: a ManiSkill sidecar without env_info.env_id"),
        (lambda p: _edit_sidecar(p, lambda d: d["episodes"].append({**d["episodes"][0], "episode_id": 7})),
         "{json}: lists episodes the .h5 does not hold (traj_7)"),
        (lambda p: _edit_sidecar(p, lambda d: d.update(episodes={})), "{json}: a ManiSkill sidecar whose `episodes` is not"),
    ],
    ids=["missing", "not-json", "no-env-info", "episode-not-in-h5", "episodes-not-a-list"],
)
def test_a_missing_or_mismatching_sidecar_is_one_line(ms_dir, tmp_path, capsys, make_bad, message):
    path = _copy(ms_dir, tmp_path)
    make_bad(path)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message.format(json=path.with_suffix(".json")) in err, err


def test_an_hdf5_file_of_neither_kind_is_refused(tmp_path, capsys):
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["data"] = np.zeros(3)
    assert main(["inspect", str(tmp_path / "other.h5")]) == 2
    assert "neither a simreel recording (no simreel metadata) nor a ManiSkill trajectory file" in capsys.readouterr().err


def test_quirks_of_a_file_are_named(ms_dir, tmp_path):
    path = _copy(ms_dir, tmp_path)

    def change(doc):
        doc["episodes"][0]["reset_kwargs"]["seed"] = [0]  # a seed list, as some ManiSkill versions write it
        doc["episodes"][1]["reset_kwargs"]["seed"] = 5  # not the episode_seed
        doc["episodes"][1]["elapsed_steps"] = 14
        doc["extra_episode_not_listed"] = True

    _edit_sidecar(path, change)
    with h5py.File(path, "a") as f:
        f.copy("traj_0", "traj_9")  # a group the sidecar does not list
    with open_reader(path) as r:
        assert r.episodes[0].seed == 0 and "reset_kwargs.seed is a list ([0])" in r.episodes[0].notes[0]
        assert r.episodes[1].seed == 1 and "reset_kwargs.seed 5 is not episode_seed 1" in r.episodes[1].notes[0]
        assert "elapsed_steps 14 in the sidecar, 15 actions in the file" in r.read_episode(1).meta.notes[-1]
        assert r.notes == ["1 group(s) the sidecar does not list (traj_9) are skipped, as ManiSkill's tools skip them"]


def test_a_gpu_recording_names_what_it_does_not_hold_and_asks_for_the_cpu_sim(ms_dir, tmp_path, capsys):
    """The sidecar of a GPU-sim recording (physx_cuda, 4 envs: reset_kwargs {}); its arrays here are CPU ones."""
    path = _copy(ms_dir, tmp_path)

    def gpu(doc):
        doc["env_info"]["env_kwargs"].update(sim_backend="physx_cuda", num_envs=4)
        for e in doc["episodes"]:
            e["reset_kwargs"] = {}

    _edit_sidecar(path, gpu)
    with open_reader(path) as r:
        assert (r.meta.sim_backend, r.meta.num_envs) == ("physx_cuda", 4)
        assert {"reset_options", "env_idx"} <= set(r.meta.unknown) and r.episodes[0].seed == 0
    assert main(["replay", str(path), "-q"]) == 2
    assert "recorded on the GPU sim (physx_cuda) and this machine has no CUDA device" in capsys.readouterr().err
    assert main(["replay", str(path), "-q", "--sim-backend", "physx_cpu"]) == 0
    out = capsys.readouterr().out
    assert "limit: sub-scenes unknown: ManiSkill does not record which parallel env ran an episode" in out


def test_a_state_mode_output_of_replay_trajectory_is_found_off_by_one(ms_dir, maniskill_env, tmp_path, capsys):
    """replay_trajectory -o state --use-env-states stores the state after step 0 as the first state."""
    converted = replay_maniskill(_copy(ms_dir, tmp_path), maniskill_env, "-o", "state", "--use-env-states")
    with open_reader(converted) as r:
        ep = r.read_episode(0)
        assert not ep.meta.initial_state_known
        assert "as in files replay_trajectory writes with --use-env-states" in ep.meta.notes[0]
        assert {"rewards", "fail"} <= set(r.meta.unknown)  # replay_trajectory records no rewards by default
    with open_reader(ms_dir / "demos.h5") as original:
        np.testing.assert_array_equal(ep.env_states["actors/cube"][0], original.read_episode(0).env_states["actors/cube"][1])
    # checked as it was made (restore, step, compare): the reset row is skipped, step 0 starts from the reset
    assert main(["replay", str(converted), "-q", "--mode", "step"]) == 0
    assert "the reset state is not compared" in capsys.readouterr().out
