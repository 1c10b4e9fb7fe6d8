"""The replaying environment is compared with the recording's fingerprint; each difference is named."""

from __future__ import annotations

from types import SimpleNamespace

from simreel.model.meta import RecordingMeta
from simreel.replay.run.fingerprint import fingerprint_differences


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


def test_a_sim_backend_is_compared_as_what_maniskill_resolves_it_to():
    """"auto" (ManiSkill's default, recorded as given by RecordEpisode) is the CPU sim for one env and the GPU sim
    for more; "cpu" and "physx_cuda:0" are its names for physx_cpu and physx_cuda."""
    cpu = SimpleNamespace(backend=SimpleNamespace(sim_backend="physx_cpu"), sim_config={})
    gpu = SimpleNamespace(backend=SimpleNamespace(sim_backend="physx_cuda"), sim_config={})

    def diffs(backend: str, env: SimpleNamespace, num_envs: int = 1) -> list[str]:
        return fingerprint_differences(RecordingMeta(env_id="PickCube-v1", sim_backend=backend, num_envs=num_envs),
                                       env, {})

    assert diffs("auto", cpu) == diffs("cpu", cpu) == diffs("physx_cuda:0", gpu) == diffs("gpu", gpu) == []
    assert diffs("auto", cpu, num_envs=4) == ["sim backend: recorded auto (physx_cuda), replaying physx_cpu"]
    assert diffs("auto", gpu) == ["sim backend: recorded auto (physx_cpu), replaying physx_cuda"]
    assert diffs("cpu", gpu) == ["sim backend: recorded cpu (physx_cpu), replaying physx_cuda"]
