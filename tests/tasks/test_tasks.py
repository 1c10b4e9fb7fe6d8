"""simreel's example tasks: registered, record-safe state layouts, reachable success, named contacts."""

from __future__ import annotations

import pytest
import torch

from simreel.sim.render_device import configure_vulkan  # noqa: E402

configure_vulkan()  # the project lavapipe, before sapien creates a device (as make_env does)

import gymnasium as gym  # noqa: E402

import simreel.tasks  # noqa: E402
from simreel.sim.make import make_env  # noqa: E402
from simreel.tasks.policies import DEFAULT_POLICIES  # noqa: E402

TASK_IDS = simreel.tasks.TASK_IDS


@pytest.fixture(scope="module")
def make():
    envs = {}

    def _make(env_id, **kwargs):
        key = (env_id, tuple(sorted(kwargs.items())))
        if key not in envs:
            envs[key] = make_env(env_id, **kwargs)  # the render device this machine has (state obs)
        return envs[key]

    yield _make
    for env in envs.values():
        env.close()


def _layout(state: dict, prefix: str = "") -> dict[str, tuple[int, ...]]:
    out = {}
    for key, value in state.items():
        if isinstance(value, dict):
            out.update(_layout(value, f"{prefix}{key}/"))
        else:
            out[f"{prefix}{key}"] = tuple(value.shape)
    return out


def _named_bodies(u) -> dict:
    """Names in simreel's pair syntax: registry actors, and `<articulation>/<link>` of registry articulations."""
    registry = u.scene.state_dict_registry
    bodies = dict(registry.actors)
    for art_name, art in registry.articulations.items():
        bodies.update({f"{art_name}/{link.name}": link for link in art.links})
    return bodies


def test_every_task_is_registered_with_end_effector_control():
    from mani_skill.utils.registration import REGISTERED_ENVS

    assert TASK_IDS == (
        "SimreelLiftCube-v1",
        "SimreelLiftCubeLeaky-v1",
        "SimreelLiftCubeStageLeaky-v1",
        "SimreelHeteroPick-v1",
        "SimreelHeteroDrawer-v1",
    )
    for env_id in TASK_IDS:
        assert env_id in REGISTERED_ENVS and env_id in gym.registry
        assert REGISTERED_ENVS[env_id].max_episode_steps <= 100
    assert set(DEFAULT_POLICIES) == set(TASK_IDS)


@pytest.mark.parametrize("env_id", TASK_IDS)
def test_state_layout_is_the_same_for_every_seed(make, env_id):
    env = make(env_id)
    u = env.unwrapped
    assert u.control_mode == "pd_ee_delta_pos"
    layouts = []
    for seed in (0, 1, 3, 6, None):
        env.reset(seed=seed)
        layouts.append(_layout(u.get_state_dict()))
        assert u.get_state().shape == (1, sum(int(torch.tensor(s[1:]).prod()) for s in layouts[-1].values()))
    assert all(layout == layouts[0] for layout in layouts), layouts


def test_heterogeneous_tasks_vary_with_the_seed_and_repeat_with_it(make):
    env = make("SimreelHeteroPick-v1")
    pick = env.unwrapped
    kinds = []
    for seed in range(8):
        env.reset(seed=seed)
        kinds.append(pick.object_kinds()[0])
    assert len(set(kinds)) >= 3, kinds
    env.reset(seed=5)
    first = pick.object_specs[0]
    env.reset(seed=1)
    env.reset(seed=5)
    assert pick.object_specs[0] == first
    assert 0.01 < first.mass < 0.25

    env = make("SimreelHeteroDrawer-v1")
    dofs = set()
    for seed in range(6):
        env.reset(seed=seed)
        dofs.add(env.unwrapped.cabinet_dofs()[0])
    assert dofs == {1, 2, 3}


@pytest.mark.parametrize("env_id", TASK_IDS)
def test_contact_pairs_name_bodies_of_the_scene(make, env_id):
    env = make(env_id)
    env.reset(seed=0)
    u = env.unwrapped
    bodies = _named_bodies(u)
    assert u.simreel_contact_pairs
    for pair in u.simreel_contact_pairs:
        a, b = pair.split(":")
        assert a in bodies and b in bodies, (pair, sorted(bodies))
        force = u.scene.get_pairwise_contact_forces(bodies[a], bodies[b])
        assert force.shape == (1, 3)


@pytest.mark.parametrize("env_id", TASK_IDS)
def test_scripted_policy_reaches_success_in_most_seeds(make, env_id):
    from mani_skill.utils.registration import REGISTERED_ENVS

    env = make(env_id)
    policy = DEFAULT_POLICIES[env_id]
    successes, rewards_rose = 0, 0
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        first_reward = None
        for _ in range(REGISTERED_ENVS[env_id].max_episode_steps):
            obs, reward, terminated, truncated, info = env.step(policy(env, obs))
            first_reward = float(reward) if first_reward is None else first_reward
            if terminated.any() or truncated.any():
                break
        successes += bool(info["success"].all())
        rewards_rose += float(reward) > first_reward
    assert successes >= 4, f"{env_id}: {successes}/6 successful"
    assert rewards_rose >= 4  # the dense reward rises along a successful episode


def test_policy_refuses_another_control_mode(make):
    from simreel.errors import UsageError

    env = make("SimreelLiftCube-v1", control_mode="pd_joint_delta_pos")
    env.reset(seed=0)
    with pytest.raises(
        UsageError, match="drive control mode 'pd_ee_delta_pos', the env uses 'pd_joint_delta_pos'"
    ):
        DEFAULT_POLICIES["SimreelLiftCube-v1"](env, None)


def _restored_height_error(env, policy, steps=8):
    """height_error at a mid-episode state of seed 0, and again after restoring it into seed 1's episode."""
    u = env.unwrapped
    obs, _ = env.reset(seed=0)
    for _ in range(steps):
        obs, *_ = env.step(policy(env, obs))
    state, recorded = u.get_state_dict(), u.evaluate()["height_error"]
    env.reset(seed=1)
    u.set_state_dict(state)
    return state, recorded, u.evaluate()["height_error"]


def test_leaky_variant_keeps_the_height_out_of_the_state_dict(make):
    policy = DEFAULT_POLICIES["SimreelLiftCube-v1"]
    state, recorded, restored = _restored_height_error(make("SimreelLiftCube-v1"), policy)
    assert "goal_height" in state
    assert torch.allclose(restored, recorded, atol=1e-5)

    state, recorded, restored = _restored_height_error(make("SimreelLiftCubeLeaky-v1"), policy)
    assert "goal_height" not in state
    assert not torch.allclose(restored, recorded, atol=1e-3)  # success/reward now follow seed 1's height


@pytest.mark.gpu
@pytest.mark.parametrize("env_id", ["SimreelHeteroPick-v1", "SimreelHeteroDrawer-v1", "SimreelLiftCube-v1"])
def test_gpu_layout_and_objects_match_the_cpu_for_any_num_envs(make, env_id):
    if not torch.cuda.is_available():
        pytest.skip("needs a CUDA GPU for the PhysX GPU sim")
    seeds = [0, 1, 3, 6]
    cpu = make(env_id).unwrapped
    cpu_layout, cpu_objects = None, []
    for seed in seeds:
        cpu.reset(seed=seed)
        cpu_layout = {k: s[1:] for k, s in _layout(cpu.get_state_dict()).items()}
        cpu_objects.append(_objects(cpu)[0])
    for num_envs in (2, 4):
        env = gym.make(env_id, obs_mode="state", num_envs=num_envs, sim_backend="gpu")
        u = env.unwrapped
        u.reset(seed=seeds[:num_envs], options={"reconfigure": True})
        layout = _layout(u.get_state_dict())
        assert {k: s[1:] for k, s in layout.items()} == cpu_layout
        assert all(s[0] == num_envs for s in layout.values())
        assert _objects(u) == cpu_objects[:num_envs]
        env.close()


def _objects(u) -> list:
    if hasattr(u, "object_specs"):
        return u.object_specs
    if hasattr(u, "cabinet_specs"):
        return u.cabinet_specs
    return [None] * u.num_envs
