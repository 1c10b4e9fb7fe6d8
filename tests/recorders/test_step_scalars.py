"""StepScalars: a step's rewards, flags and scalar info, copied out after the step and converted a block at a time,
record exactly what the env reported — including values the env later changes in place and info entries that come
and go or change shape."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simreel.formats import open_reader
from simreel.model.state_tree import to_numpy
from simreel.recorders import RecordWrapper
from simreel.recorders.step_scalars import StepScalars
from simreel.sim.make import make_env

_BIG = 2**60 + 1
"""An int64 info value float64 cannot hold exactly."""


@pytest.fixture(scope="module")
def odd_info_task():
    """PickCube whose info also holds a 0-d tensor, an int64 beyond float64, an entry present on even steps only,
    one that changes shape at step 3 and a plain Python list the task changes in place at every step."""
    from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv
    from mani_skill.utils.registration import register_env

    @register_env("SimreelTestOddInfo-v1", max_episode_steps=8)
    class OddInfo(PickCubeEnv):
        def evaluate(self):
            info = super().evaluate()
            t = int(self._elapsed_steps[0]) if hasattr(self, "_elapsed_steps") else 0
            info["bonus"] = torch.tensor(0.25 * t)
            info["big"] = torch.tensor([_BIG + t], dtype=torch.int64)
            if t % 2 == 0:
                info["sometimes"] = torch.tensor([True])
            info["shape_changes"] = torch.tensor([[1.0, 2.0]] if t == 3 else [1.5])
            self._tally = getattr(self, "_tally", [0.0])
            self._tally[0] = 0.5 * t
            info["tally"] = self._tally
            return info

    return "SimreelTestOddInfo-v1"


def test_odd_info_entries_are_recorded_by_the_per_step_rules(tmp_path, odd_info_task):
    env = RecordWrapper(make_env(odd_info_task), tmp_path / "odd.h5", contacts="none")
    env.reset(seed=0)
    for _ in range(6):
        env.step(np.zeros(env.action_space.shape, np.float32))
    env.close()
    with open_reader(tmp_path / "odd.h5") as r:
        ep = r.read_episode(0)
    steps = np.arange(1, 7)
    np.testing.assert_array_equal(ep.info["bonus"], np.float32(0.25 * steps))  # a 0-d value: every env's
    assert ep.info["big"].dtype == np.int64
    np.testing.assert_array_equal(ep.info["big"], _BIG + steps)  # exact, not through float64
    np.testing.assert_array_equal(ep.info["sometimes"], steps % 2 == 0)  # absent: False
    np.testing.assert_array_equal(ep.info["shape_changes"], np.where(steps == 3, 0.0, 1.5))  # another shape: 0
    np.testing.assert_array_equal(ep.info["elapsed_steps"], steps)  # ManiSkill updates this tensor in place
    np.testing.assert_array_equal(ep.info["tally"], np.float32(0.5 * steps))  # so does the task this list


def test_a_block_converts_to_what_each_step_reported(odd_info_task):
    """The block conversion (one numpy call for all fields) equals converting each step's values on their own."""
    from simreel.recorders.step_scalars import StepScalars, scalar_info

    env = make_env("PickCube-v1")
    env.reset(seed=3)
    u = env.unwrapped
    layout = scalar_info(u.get_info(), 1)
    scalars = StepScalars(1, [(f"info/{k}", a.dtype) for k, a in layout.items()])
    captures, reported = [], []
    rng = np.random.default_rng(3)
    for _ in range(20):
        _, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        captures.append(scalars.capture(reward, terminated, truncated, info))
        reported.append({"rewards": to_numpy(reward).astype(np.float32), "terminated": to_numpy(terminated).copy(),
                         "truncated": to_numpy(truncated).copy(), "success": to_numpy(info["success"]).copy(),
                         "fail": np.zeros(1, bool), **{f"info/{k}": to_numpy(info[k]).copy() for k in layout}})
    env.close()
    rows = scalars.rows(captures)
    assert set(rows) == set(reported[0])
    for name, got in rows.items():
        want = np.stack([r[name] for r in reported])
        assert got.dtype == (np.float32 if name == "rewards" else want.dtype), name
        np.testing.assert_array_equal(got, want, err_msg=name)
    assert rows["info/elapsed_steps"][-1, 0] == 20 and rows["info/elapsed_steps"][0, 0] == 1


def test_a_capture_holds_only_plain_numbers_and_converts_as_the_recorder_reads_success():
    """What a step captures goes to the writer process: a value that holds no numbers (a dict with a lock, None inside
    a list) is captured as None and recorded as zeros, and the success flags the recorder reads from the captures
    (`ScalarRows.field`) are the ones written (None was read as NaN, hence True, by the one path and False by the
    other)."""
    import pickle
    import threading

    scalars = StepScalars(1, [("info/is_grasped", np.dtype(bool))])
    odd = scalars.capture([0.5], [False], [False], {"success": [None], "fail": {"why": threading.Lock()},
                                                    "is_grasped": 1})
    captures = pickle.loads(pickle.dumps([odd, scalars.capture(np.array([1.0]), np.array([True]), np.array([False]),
                                                               {"success": np.array([True])})]))
    rows = scalars.rows(captures)
    assert rows["success"].tolist() == scalars.rows.field(captures, "success").tolist() == [[False], [True]]
    assert rows["fail"].tolist() == [[False], [False]] and rows["info/is_grasped"].tolist() == [[True], [False]]
    assert rows["rewards"].tolist() == [[0.5], [1.0]]


def test_the_success_flags_of_an_episode_end_are_the_ones_written():
    """`last_and_any`, which the recorder reads as an episode ends (in Python where each step gave bools), answers as
    the rows written do, whatever each step captured for each env."""
    scalars = StepScalars(2, [("info/success", np.dtype(bool))])

    def step(success):
        return scalars.capture(torch.zeros(2), torch.zeros(2, dtype=torch.bool), torch.zeros(2, dtype=torch.bool),
                               {} if success is None else {"success": success})

    blocks = [
        [step(torch.tensor([False, True])), step(torch.tensor([True, False]))],  # bools: read in Python
        [step(torch.tensor([True, True])), step(None)],  # absent at the end: zeros
        [step([None, 1]), step([0.5, 0])],  # not bools: read as the rows
        [step(torch.tensor([False, False]))],
    ]
    for captures in blocks:
        rows = scalars.rows(captures)["success"]
        for env in (0, 1):
            assert scalars.rows.last_and_any(captures, "success", env) == (bool(rows[-1, env]), bool(rows[:, env].any()))
    assert scalars.rows.last_and_any(blocks[0], "success", 0) == (True, True)
    assert scalars.rows.last_and_any(blocks[0], "success", 1) == (False, True)


def test_the_success_flags_of_an_episode_end_ignore_a_list_that_is_not_one_per_env():
    """Regression: a success list of another length than the envs was read at `env` although the rows hold zeros
    for it (an info entry of another shape): the episode's success said True, its success rows False."""
    scalars = StepScalars(1, [("info/success", np.dtype(bool))])
    captures = [scalars.capture([0.0], [False], [False], {"success": [True, False]})]
    assert scalars.rows(captures)["success"].tolist() == [[False]]
    assert scalars.rows.last_and_any(captures, "success", 0) == (False, False)
