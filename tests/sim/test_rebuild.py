"""A recording's metadata rebuilds its env: same task, control mode and sim config."""

from __future__ import annotations

import numpy as np

from simreel.formats import open_reader
from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env
from simreel.sim.rebuild import env_from_meta


def test_env_from_meta_rebuilds_sim_config_and_control_mode(tmp_path):
    env = make_env("PickCube-v1", control_mode="pd_ee_delta_pos", sim_config={"sim_freq": 200, "control_freq": 20})
    rec = RecordWrapper(env, tmp_path / "r.h5")
    rec.reset(seed=0)
    rec.step(np.zeros(rec.action_space.shape, np.float32))
    rec.close()
    with open_reader(tmp_path / "r.h5") as r:
        meta = r.meta
    assert "sim_config" not in meta.env_kwargs and meta.sim_freq == 200
    again = env_from_meta(meta)
    try:
        u = again.unwrapped
        assert (u.sim_freq, u.control_freq, u.control_mode) == (200, 20, "pd_ee_delta_pos")
    finally:
        again.close()


def test_simreel_tasks_need_no_import(tmp_path):
    env = make_env("SimreelHeteroPick-v1")
    assert "object" in env.unwrapped.scene.state_dict_registry.actors
    env.close()
