"""Batched recording on the PhysX GPU sim: every env's episode is its own episode, partial resets end
only those envs' episodes, heterogeneous layouts do not depend on num_envs. Needs CUDA; skipped elsewhere."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU for the PhysX GPU sim"),
]


def test_batched_recording_splits_envs_and_partial_resets(tmp_path):
    from simreel.formats import open_reader
    from simreel.model.state_tree import flatten, to_numpy
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    n = 8
    env = RecordWrapper(make_env("PickCube-v1", num_envs=n, sim_backend="physx_cuda"), tmp_path / "g.h5")
    env.reset(seed=list(range(n)))
    truth = []
    for t in range(6):
        env.step(env.action_space.sample())
        truth.append(flatten(env.unwrapped.get_state_dict()))
        if t == 2:
            env.reset(seed=[100, 101], options={"env_idx": torch.tensor([1, 5])})
    env.close()
    with open_reader(tmp_path / "g.h5") as r:
        eps = {(m.env_idx, m.seed): r.read_episode(m.index) for m in r.episodes}
    assert len(eps) == n + 2
    assert eps[(1, 1)].length == 3 and eps[(1, 100)].length == 3 and eps[(0, 0)].length == 6
    cube = to_numpy(truth[-1]["actors/cube"])
    np.testing.assert_array_equal(eps[(0, 0)].env_states["actors/cube"][-1], cube[0])
    np.testing.assert_array_equal(eps[(5, 101)].env_states["actors/cube"][-1], cube[5])
    assert eps[(3, 3)].contact_forces.shape == (6, len(r.meta.contact_channels), 3)


@pytest.mark.parametrize("num_envs", [1, 4, 16])
def test_heterogeneous_layout_does_not_depend_on_num_envs(tmp_path, num_envs):
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    env = RecordWrapper(make_env("SimreelHeteroDrawer-v1", num_envs=num_envs, sim_backend="physx_cuda"),
                        tmp_path / f"h{num_envs}.h5")
    assert env.meta.state_layout["articulations/cabinet"].shape == (19,)
    env.close()


def test_the_record_command_records_exactly_the_episodes_asked_of_parallel_envs(tmp_path, capsys):
    """`record -n 3 --num-envs 4`: four episodes run at once and end together at the time limit; three are kept, with
    seeds 0, 1, 2."""
    from simreel.cli.main import main
    from simreel.formats import open_reader

    out = tmp_path / "p.h5"
    assert main(["record", "PickCube-v1", "-o", str(out), "-n", "3", "--num-envs", "4", "--max-steps", "5",
                 "--sim-backend", "physx_cuda", "-q"]) == 0
    with open_reader(out) as r:
        assert sorted((m.seed, m.length) for m in r.episodes) == [(0, 5), (1, 5), (2, 5)]


def test_unseeded_partial_resets_on_the_gpu_sim_are_warned_of_once_and_counted(tmp_path, capsys):
    """Several envs on the GPU sim: one draw serves every env and nothing captures it, so a replay cannot remake an
    unseeded reset: the recorder says so once; `simreel inspect` counts the episodes without generator states."""
    import warnings

    from simreel.cli.main import main
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    env = RecordWrapper(make_env("PickCube-v1", num_envs=4, sim_backend="physx_cuda"), tmp_path / "u.h5")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env.reset(seed=list(range(4)))
        for t in range(4):
            env.step(env.action_space.sample())
            if t in (1, 2):
                env.reset(options={"env_idx": torch.tensor([0, 2])})
        env.close()
    warned = [str(w.message) for w in caught if "without a seed" in str(w.message)]
    assert len(warned) == 1 and warned[0].startswith("simreel: reset() without a seed on 4 envs: a replay cannot")
    assert (env.unseeded, env.unseeded_remade) == (4, 0)
    capsys.readouterr()
    assert main(["inspect", str(tmp_path / "u.h5")]) == 0
    assert ("unseeded: 4 episode(s) reset without a seed; 0 with their random generators' states"
            in capsys.readouterr().out)
