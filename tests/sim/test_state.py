"""Restoring a recorded state restores all of it: task state, custom keys and the controller's targets."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simreel.formats import open_reader
from simreel.model.state_tree import flatten, unflatten
from simreel.replay.run.engine import EpisodeReplayer
from simreel.sim.state import restore_state, state_row


def _restore_into_another_episode_then_step(path, *, t: int, plain: bool) -> dict[str, float]:
    """Put an env elsewhere (other seed, other actions), restore recorded state t, step action t: error per key."""
    with open_reader(path) as r:
        ep = r.read_episode(0)
        with EpisodeReplayer(r.meta) as rp:
            env, u = rp.env, rp.u
            env.reset(seed=1234)
            env.action_space.seed(0)
            for _ in range(4):
                env.step(env.action_space.sample())
            row = state_row(ep.env_states, t)
            if plain:  # what ManiSkill's own set_state_dict does
                u.set_state_dict(unflatten({k: torch.as_tensor(v) for k, v in row.items()}))
            else:
                restore_state(u, row, elapsed_steps=t)
            env.step(ep.actions[t])
            now = flatten(u.get_state_dict())
            return {k: float(np.abs(now[k][0] - ep.env_states[k][t + 1]).max()) for k in now}


@pytest.mark.parametrize(
    "control_mode,key",
    [("pd_ee_target_delta_pos", "controller/arm/target_pose"), ("pd_joint_target_delta_pos", "controller/arm/target_qpos")],
)
def test_controller_targets_survive_a_restore(record, control_mode, key):
    path = record("PickCube-v1", 1, 12, "--control-mode", control_mode)
    with open_reader(path) as r:
        assert key in r.meta.state_layout
    ours = _restore_into_another_episode_then_step(path, t=8, plain=False)
    assert ours[key] == 0.0
    assert ours["articulations/panda"] < 1e-4
    # ManiSkill's set_state_dict alone keeps the controller's own (other episode's) target: the arm goes elsewhere
    plain = _restore_into_another_episode_then_step(path, t=8, plain=True)
    assert plain[key] > 1e-2
    assert plain["articulations/panda"] > 1e-2


def test_custom_state_and_step_count_are_restored(record):
    path = record("SimreelLiftCube-v1", 2, 20)
    with open_reader(path) as r:
        ep = r.read_episode(1)
        with EpisodeReplayer(r.meta) as rp:
            rp.env.reset(seed=999)
            restore_state(rp.u, state_row(ep.env_states, 5), elapsed_steps=5)
            assert rp.u.goal_height[0].item() == pytest.approx(float(ep.env_states["goal_height"][5]))
            assert int(rp.u.elapsed_steps[0]) == 5


@pytest.mark.parametrize(
    "env_id,extra,fast",
    [
        ("PickCube-v1", ("--control-mode", "pd_ee_target_delta_pos"), True),  # + controller state
        ("PegInsertionSide-v1", (), True),  # merged views in the registry
        ("SimreelLiftCube-v1", (), True),  # + declared custom state
        ("SimreelHeteroDrawer-v1", (), False),  # padded merged articulation: get_state_dict() only
    ],
)
def test_fast_state_reader_is_bit_identical_or_not_used(record, env_id, extra, fast):
    from simreel.sim.state import FastStateReader

    path = record(env_id, 1, 12, *extra)
    with open_reader(path) as r:
        ep = r.read_episode(0)
        with EpisodeReplayer(r.meta) as rp:
            rp.reset_for(ep.meta)
            reader = FastStateReader.for_env(rp.u)
            assert (reader is not None) == fast
            if reader is None:
                return
            assert reader.equals(flatten(rp.u.get_state_dict()))  # the recorder's check at a reset
            for a in ep.actions[:6]:
                rp.u.step(a)
                got, want = reader.read(), flatten(rp.u.get_state_dict())
                assert list(got) == list(want)  # the same keys in the same order: writers store them so
                for k in want:
                    assert got[k].dtype == want[k].dtype and np.array_equal(got[k], want[k]), k


def test_the_fast_readers_check_is_bit_for_bit_and_hands_back_what_it_checked():
    """Regression: the check compared values, so a reader that read 0.0 where `get_state_dict()` held -0.0 passed it
    (the recorder then stores other bits than the env's state dict). `capture_equal_to` gives the capture it checked,
    which a recorder stores as the reset row; any other key order, bit or extra leaf is no capture."""
    from simreel.sim.make import make_env
    from simreel.sim.state import FastStateReader

    env = make_env("PickCube-v1", control_mode="pd_ee_target_delta_pos")  # + controller state, read as an extra
    try:
        env.reset(seed=0)
        reader = FastStateReader.for_env(env.unwrapped)
        state = flatten(env.unwrapped.get_state_dict())
        assert reader.capture_equal_to(state) == reader.capture() and reader.equals(state)
        velocities = state["actors/cube"].copy()
        assert velocities[0, 7] == 0.0  # at rest after a reset
        velocities[0, 7] = -0.0
        assert not reader.equals({**state, "actors/cube": velocities})
        assert reader.capture_equal_to({**state, "actors/cube": velocities}) is None
        assert reader.capture_equal_to(dict(reversed(state.items()))) is None
        target = state["controller/arm/target_pose"]
        assert reader.capture_equal_to({**state, "controller/arm/target_pose": np.nextafter(target, 1)}) is None
    finally:
        env.close()
