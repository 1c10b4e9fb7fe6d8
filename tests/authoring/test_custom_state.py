"""Declared custom state: added to the state dict, restored per sub-scene, refused when missing."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simreel.authoring.custom_state import (
    CustomStateError,
    CustomStateMixin,
    custom_state_names,
    get_custom_state,
    set_custom_state,
)
from simreel.errors import SimreelError
from simreel.sim.render_device import configure_vulkan

configure_vulkan()  # the project lavapipe, before sapien creates a device (as make_env does)


# --------------------------------------------------------------------------------------------------
# The mixin on a small fake batched env (3 sub-scenes), for the logic that needs num_envs > 1
# --------------------------------------------------------------------------------------------------
class _FakeBaseEnv:
    """Stands in for BaseEnv: one actor state, and a record of what set_state_dict received."""

    def __init__(self, num_envs: int = 3) -> None:
        self.num_envs = num_envs
        self.box = torch.arange(num_envs * 13, dtype=torch.float32).reshape(num_envs, 13)
        self.restored: list[tuple[dict, object]] = []

    def get_state_dict(self):
        return {"actors": {"box": self.box.clone()}}

    def set_state_dict(self, state, env_idx=None):
        self.restored.append((state, env_idx))


class _FakeTask(CustomStateMixin, _FakeBaseEnv):
    custom_state = ("goal_height", "goal_pos")

    def __init__(self, num_envs: int = 3) -> None:
        super().__init__(num_envs)
        self.goal_height = torch.tensor([0.1, 0.2, 0.3])
        self.goal_pos = torch.arange(9, dtype=torch.float32).reshape(3, 3)
        self._init_raw_state = self.get_state_dict()


def test_state_dict_carries_clones_of_the_declared_attributes_at_top_level():
    env = _FakeTask()
    state = env.get_state_dict()
    assert list(state) == ["actors", "goal_height", "goal_pos"]
    assert torch.equal(state["goal_height"], env.goal_height)
    state["goal_height"][0] = 9.0
    assert env.goal_height[0] == pytest.approx(0.1)  # a clone, not the attribute itself


def test_restore_writes_every_row_without_env_idx():
    env = _FakeTask()
    state = env.get_state_dict()
    env.goal_height[:] = 0
    env.set_state_dict(state)
    assert torch.allclose(env.goal_height, torch.tensor([0.1, 0.2, 0.3]))
    assert env.restored[-1][0] is state  # the sim part still goes to BaseEnv


@pytest.mark.parametrize(
    "env_idx", [torch.tensor([0, 2]), [0, 2], np.array([0, 2]), torch.tensor([True, False, True])]
)
def test_restore_with_env_idx_writes_only_those_rows(env_idx):
    env = _FakeTask()
    state = {"actors": {}, "goal_height": torch.tensor([7.0, 8.0]), "goal_pos": -torch.ones(2, 3)}
    env.set_state_dict(state, env_idx)
    assert env.goal_height.tolist() == pytest.approx([7.0, 0.2, 8.0])
    assert env.goal_pos[1].tolist() == [3.0, 4.0, 5.0]
    assert env.goal_pos[[0, 2]].eq(-1).all()


def test_restore_accepts_numpy_values_from_a_file():
    env = _FakeTask()
    state = {"goal_height": np.array([0.5, 0.6, 0.7], dtype=np.float64), "goal_pos": np.zeros((3, 3))}
    set_custom_state(env, state)
    assert env.goal_height.dtype == torch.float32
    assert env.goal_height.tolist() == pytest.approx([0.5, 0.6, 0.7])


def test_missing_key_is_refused_before_the_sim_is_touched():
    env = _FakeTask()
    state = env.get_state_dict()
    del state["goal_pos"]
    with pytest.raises(CustomStateError) as e:
        env.set_state_dict(state)
    assert str(e.value) == (
        "state dict has no 'goal_pos', custom state that _FakeTask declares; the state was saved without it "
        "(by an older task version or a hand-made dict): save it with env.get_state_dict(), or re-record"
    )
    assert isinstance(e.value, SimreelError)
    assert env.restored == []


def test_wrong_row_count_names_the_key_and_the_expected_shape():
    env = _FakeTask()
    state = {"goal_height": torch.zeros(3), "goal_pos": torch.zeros(3, 3)}
    with pytest.raises(
        CustomStateError,
        match=r"state\['goal_height'\] has shape \(3,\), expected \(2,\) "
        r"\(one row per restored sub-scene, env_idx=\[0, 1\]\)",
    ):
        env.set_state_dict(state, torch.tensor([0, 1]))


@pytest.mark.parametrize(
    "value, found",
    [(0.3, "float"), (torch.zeros(2), "(2,)"), (torch.zeros(3, 2, 2), "(3, 2, 2)")],
)
def test_a_declared_attribute_must_be_batched(value, found):
    env = _FakeTask()
    env.goal_height = value
    with pytest.raises(CustomStateError) as e:
        env.get_state_dict()
    assert str(e.value) == (
        "_FakeTask.goal_height must be a torch tensor of shape (num_envs,) or (num_envs, k) with num_envs=3 "
        f"to be custom state, found {found}; keep one row per sub-scene"
    )


def test_a_declared_attribute_must_exist():
    env = _FakeTask()
    del env.goal_pos
    with pytest.raises(CustomStateError, match="declares custom state 'goal_pos' but has no attribute"):
        get_custom_state(env)


def test_declaration_must_be_a_tuple_of_names():
    env = _FakeTask()
    env.custom_state = "goal_height"
    with pytest.raises(CustomStateError, match="custom_state must be a tuple of attribute names"):
        custom_state_names(env)


def test_flat_state_vector_round_trips_custom_state_per_env():
    from mani_skill.utils.common import flatten_state_dict

    env = _FakeTask()
    flat = flatten_state_dict(env.get_state_dict(), use_torch=True)
    assert flat.shape == (3, 13 + 1 + 3)
    env.goal_height[:] = 0
    env.goal_pos[:] = 0
    env.set_state(flat[[1]], torch.tensor([1]))
    assert env.goal_height.tolist() == pytest.approx([0.0, 0.2, 0.0])
    assert env.goal_pos[1].tolist() == [3.0, 4.0, 5.0]
    assert torch.equal(env.restored[-1][0]["actors"]["box"], env.box[[1]])


def test_flat_state_of_another_layout_is_refused():
    env = _FakeTask()
    with pytest.raises(
        CustomStateError, match="flat state has 20 values per env, the env's state dict layout has 17"
    ):
        env.set_state(torch.zeros(3, 20))


# --------------------------------------------------------------------------------------------------
# On a real task: SimreelLiftCube-v1 declares goal_height
# --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def lift_env():
    import simreel.tasks  # noqa: F401  (registers the tasks)
    from simreel.sim.make import make_env

    env = make_env("SimreelLiftCube-v1")  # the render device this machine has (state obs)
    yield env
    env.close()


def test_real_task_state_dict_holds_goal_height(lift_env):
    lift_env.reset(seed=0)
    u = lift_env.unwrapped
    state = u.get_state_dict()
    assert state["goal_height"].shape == (1,)
    assert torch.equal(state["goal_height"], u.goal_height)
    assert custom_state_names(lift_env) == ("goal_height",)


def test_real_task_restore_brings_back_goal_height_and_what_depends_on_it(lift_env):
    u = lift_env.unwrapped
    lift_env.reset(seed=0)
    state, info = u.get_state_dict(), u.evaluate()
    lift_env.reset(seed=1)
    assert not torch.equal(u.goal_height, state["goal_height"])
    u.set_state_dict(state)
    assert torch.equal(u.goal_height, state["goal_height"])
    assert torch.allclose(u.evaluate()["height_error"], info["height_error"], atol=1e-6)


def test_real_task_flat_state_and_partial_restore(lift_env):
    u = lift_env.unwrapped
    lift_env.reset(seed=2)
    flat, height = u.get_state(), u.goal_height.clone()
    lift_env.reset(seed=3)
    u.set_state(flat, torch.tensor([0]))
    assert torch.equal(u.goal_height, height)
    assert torch.allclose(u.get_state(), flat, atol=1e-6)


def test_real_task_reset_to_env_states_restores_goal_height(lift_env):
    u = lift_env.unwrapped
    lift_env.reset(seed=4)
    state = u.get_state_dict()
    lift_env.reset(seed=5, options={"reset_to_env_states": {"env_states": state}})
    assert torch.equal(u.goal_height, state["goal_height"])
