"""ManiSkill's own `replay_trajectory` reads a simreel .h5 (its traj_N groups + the JSON sidecar) and replays it.

ManiSkill's tool builds its env with render_mode="rgb_array", so it needs a Vulkan device: here the software
one (lavapipe) that `make setup` fetches, made visible to ManiSkill through VK_ICD_FILENAMES.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest
from support.maniskill_files import replay_maniskill

from simreel.formats import open_reader


def test_maniskill_replay_trajectory_replays_a_simreel_recording(record, maniskill_env, tmp_path):
    src = record("PickCube-v1", 2, 20)
    h5 = tmp_path / "pick.h5"
    shutil.copy(src, h5)
    shutil.copy(src.with_suffix(".json"), h5.with_suffix(".json"))
    replayed = replay_maniskill(h5, maniskill_env)
    assert replayed.name == "pick.state.pd_joint_delta_pos.physx_cpu.h5"
    with h5py.File(replayed, "r") as f, open_reader(h5) as r:
        for i in range(2):
            ep = r.read_episode(i)
            np.testing.assert_array_equal(f[f"traj_{i}/actions"][()], ep.actions)
            # ManiSkill's replay reproduced simreel's recording bit for bit (same seeds, same reset kwargs)
            for key in ("actors/cube", "articulations/panda"):
                np.testing.assert_array_equal(f[f"traj_{i}/env_states/{key}"][()], ep.env_states[key])


def test_maniskills_replay_re_renders_rgb_from_a_state_only_recording(record, maniskill_env, tmp_path):
    """ManiSkill builds demos for training by re-rendering them (`replay_trajectory -o rgb`). The sidecar of a
    state-only recording said render_backend "none", which ManiSkill passed on and then failed ("'NoneType' object
    has no attribute 'visibility'"); a copy of a ManiSkill file that named no render backend said so too."""
    src = record("PickCube-v1", 1, 5)
    h5 = tmp_path / "pick.h5"
    shutil.copy(src, h5)
    shutil.copy(src.with_suffix(".json"), h5.with_suffix(".json"))
    assert "render_backend" not in json.loads(h5.with_suffix(".json").read_text())["env_info"]["env_kwargs"]
    replayed = replay_maniskill(h5, maniskill_env, "-o", "rgb")
    with h5py.File(replayed, "r") as f:
        assert f["traj_0/obs/sensor_data/base_camera/rgb"].shape == (6, 128, 128, 3)


def test_states_mode_re_renders_rgb_observations(record, lavapipe_env, tmp_path):
    """`--mode states --obs-mode rgb -o`: camera images regenerated from the recorded states (software Vulkan)."""
    src = record("PickCube-v1", 2, 20)
    out = tmp_path / "rgb.h5"
    run = subprocess.run(
        [sys.executable, "-m", "simreel", "replay", str(src), "--episodes", "1", "--mode", "states",
         "--obs-mode", "rgb", "-o", str(out), "-q"],
        env=lavapipe_env, capture_output=True, text=True, timeout=300,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    with open_reader(out) as r:
        assert r.meta.obs_mode == "rgb" and [m.index for m in r.episodes] == [1]
        ep = r.read_episode(1)
        rgb = ep.obs["sensor_data/base_camera/rgb"]
        assert rgb.shape == (21, 128, 128, 3) and rgb.dtype == np.uint8
        assert np.abs(rgb[0].astype(int) - rgb[-1]).mean() > 1  # the arm moved between the first and last frame
        with open_reader(src) as orig:
            # the states are the recorded ones, read back after restoring (get -> set -> get: <= 1.5e-8)
            np.testing.assert_allclose(ep.env_states["actors/cube"], orig.read_episode(1).env_states["actors/cube"],
                                       atol=1e-6)


@pytest.mark.parametrize(
    ("obs_mode", "extra"),
    [("state", ["--record-obs"]), ("state_dict", ["--record-obs"]), ("state", [])],
    ids=["state-array", "state_dict-nested", "no-observations"],
)
def test_maniskills_dataset_loader_reads_simreel_recordings(record, obs_mode, extra):
    """ManiSkillTrajectoryDataset gets ManiSkill's layout: `obs` one array for obs_mode state, nested groups for a
    dict observation, an empty group when none were recorded (as ManiSkill's obs_mode=none demos)."""
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset

    from simreel.model.state_tree import flatten

    path = record("PickCube-v1", 2, 8, "--obs-mode", obs_mode, *extra)
    with open_reader(path) as r:
        episodes = [r.read_episode(m.index) for m in r.episodes]
    data = ManiSkillTrajectoryDataset(str(path))  # keeps its h5py file open (with HDF5's locking) from here on
    np.testing.assert_array_equal(data.actions, np.concatenate([ep.actions for ep in episodes]))
    np.testing.assert_array_equal(data.rewards, np.concatenate([ep.rewards for ep in episodes]))
    if not extra:
        assert data.obs == {}
        return
    assert isinstance(data.obs, np.ndarray) == (obs_mode == "state")
    loaded = {"state": data.obs} if obs_mode == "state" else flatten(data.obs)
    assert set(loaded) == set(episodes[0].obs)
    for key, values in loaded.items():  # the loader drops each episode's last observation
        np.testing.assert_array_equal(values, np.concatenate([ep.obs[key][:-1] for ep in episodes]))
