"""StepBuffer: per-env rows of a batched block, the bookkeeping partial resets rely on."""

from __future__ import annotations

import numpy as np

from simreel.recorders.step_buffer import StepBuffer


def test_envs_take_their_own_rows_across_partial_resets():
    buf = StepBuffer(capacity=4, num_envs=3)
    for t in range(3):
        buf.push({"x": np.array([10 * t + 0, 10 * t + 1, 10 * t + 2]), "y": np.full((3, 2), t)})
    # env 1's episode ends after step 2 (a partial reset): it takes its rows, the others keep theirs
    np.testing.assert_array_equal(buf.take(1)["x"], [1, 11, 21])
    assert buf.pending(1) == 0 and buf.pending(0) == 3
    buf.push({"x": np.array([30, 31, 32]), "y": np.full((3, 2), 3)})
    assert buf.full
    np.testing.assert_array_equal(buf.take(0)["x"], [0, 10, 20, 30])
    np.testing.assert_array_equal(buf.take(1)["x"], [31])  # the new episode's first row only
    np.testing.assert_array_equal(buf.take(2)["y"][:, 0], [0, 1, 2, 3])
    buf.rewind()
    assert buf.rows == 0 and all(buf.pending(i) == 0 for i in range(3))
    buf.push({"x": np.array([40, 41, 42]), "y": np.full((3, 2), 4)})
    np.testing.assert_array_equal(buf.take(2)["x"], [42])


class _Doubling:
    """A row source (its `rows`): each capture (a list of one number per env) becomes row `2 * capture` of field "x"."""

    def __init__(self):
        self.calls = 0

    def rows(self, captures):
        self.calls += 1
        return {"x": 2 * np.array(captures)}


def test_captures_become_rows_once_per_block_in_their_own_rows():
    source = _Doubling()
    buf = StepBuffer(capacity=4, num_envs=2)
    buf.push({"y": np.array([0, 1])}, ((source.rows, [10, 11]),))
    buf.push({"x": np.array([-1, -2]), "y": np.array([2, 3])})  # a step whose x was read at once
    buf.push({"y": np.array([4, 5])}, ((source.rows, [30, 31]),))
    assert source.calls == 0  # nothing converted before the rows are taken
    np.testing.assert_array_equal(buf.take(0)["x"], [20, -1, 60])
    np.testing.assert_array_equal(buf.take(1)["x"], [22, -2, 62])
    assert source.calls == 1  # one conversion for the block, whoever takes first
    buf.push({"y": np.array([6, 7])}, ((source.rows, [40, 41]),))
    np.testing.assert_array_equal(buf.take(1)["x"], [82])
    buf.rewind()
    buf.push({"y": np.array([8, 9])}, ((source.rows, [50, 51]),))
    np.testing.assert_array_equal(buf.take(0)["x"], [100])  # a rewind drops what was captured before it
