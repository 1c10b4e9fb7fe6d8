"""The replaying environment is compared with the recording's fingerprint; each difference is named."""

from __future__ import annotations

from types import SimpleNamespace

from simreel.episode import RecordingMeta
from simreel.replay.fingerprint import fingerprint_differences


def test_each_difference_is_named():
    meta = RecordingMeta(
        env_id="PickCube-v1",
        sim_backend="physx_cpu",
        sim_config={"sim_freq": 100, "scene_config": {"solver_position_iterations": 15}},
        versions={"mani_skill": "3.0.1", "sapien": "3.0.3", "simreel": "0.0.9"},
    )
    env = SimpleNamespace(
        backend=SimpleNamespace(sim_backend="physx_cuda"),
        sim_config={"sim_freq": 500, "scene_config": {"solver_position_iterations": 15}},
    )
    diffs = fingerprint_differences(meta, env, {"mani_skill": "3.0.2", "sapien": "3.0.3", "simreel": "0.1.0"})
    assert diffs == [
        "mani_skill: recorded 3.0.1, replaying 3.0.2",
        "sim backend: recorded physx_cpu, replaying physx_cuda",
        "sim_config.sim_freq: recorded 100, replaying 500",
    ]
    same = SimpleNamespace(backend=SimpleNamespace(sim_backend="physx_cpu"), sim_config=meta.sim_config)
    assert fingerprint_differences(meta, same, {"mani_skill": "3.0.1", "sapien": "3.0.3"}) == []
