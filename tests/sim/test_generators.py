"""The generator states an unseeded reset draws from: captured without drawing, set for a reset, then put back."""

from __future__ import annotations

import random

import numpy as np
import pytest
import torch

from simreel.errors import MetadataError
from simreel.sim.generators import capture_generators, consumed_generators, recorded_generators


def _draws() -> tuple[list[float], list[float], float]:
    return torch.rand(3).tolist(), np.random.rand(3).tolist(), random.random()


def _seed_all() -> None:
    torch.manual_seed(1), np.random.seed(2), random.seed(3)


def test_capturing_draws_nothing_and_keeps_only_what_was_consumed():
    _seed_all()
    untouched = _draws()
    _seed_all()
    before = capture_generators()
    assert _draws() == untouched  # reading the states drew nothing
    before = capture_generators()
    torch.rand(1)  # a reset that draws from torch's generator alone
    assert sorted(consumed_generators(before)) == ["torch"]


def test_the_recorded_states_are_set_in_the_block_and_the_process_s_put_back_after():
    _seed_all()
    before = capture_generators()
    recorded = _draws()
    states = consumed_generators(before)
    assert sorted(states) == ["numpy", "python", "torch"]
    ours = capture_generators()
    with recorded_generators(states):
        assert _draws() == recorded
    assert capture_generators() == ours  # the process's own generators as they were


def test_the_env_s_own_generators_are_set_and_go_on(tmp_path):
    from types import SimpleNamespace

    env = SimpleNamespace(_batched_episode_rng=SimpleNamespace(rngs=[np.random.RandomState(5)]))
    before = capture_generators(env)
    drawn = env._batched_episode_rng.rngs[0].rand(2).tolist()
    states = consumed_generators(before, env)
    assert sorted(states) == ["episode"]
    with recorded_generators(states, env):
        pass
    assert env._batched_episode_rng.rngs[0].rand(2).tolist() == drawn  # set, and not put back


@pytest.mark.parametrize("states", [{"torch": "not base64!"}, {"dice": "AAAA"}, {"numpy": 5},
                                    {"torch": "eNpjYAAAAAQAAQ=="}])
def test_damaged_states_are_a_metadata_error(states):
    ours = capture_generators()
    with pytest.raises(MetadataError, match="reset_generators"), recorded_generators(states):
        pass
    assert capture_generators() == ours
