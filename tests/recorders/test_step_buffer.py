"""StepBuffer: per-env rows of a batched block, the bookkeeping partial resets rely on."""

from __future__ import annotations

import numpy as np
import pytest

from simreel.errors import EpisodeLayoutError
from simreel.recorders.step_buffer import FieldsChanged, StepBuffer


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
    """A row source: each capture (a list of one number per env) becomes row `2 * capture` of field "x"."""

    names = ("x",)

    def __init__(self):
        self.calls = 0

    def __call__(self, captures):
        self.calls += 1
        return {"x": 2 * np.array(captures)}


def test_captures_become_rows_once_per_block_in_their_own_rows():
    source = _Doubling()
    buf = StepBuffer(capacity=4, num_envs=2)
    buf.push({"y": np.array([0, 1])}, ((source, [10, 11]),))
    buf.push({"x": np.array([-1, -2]), "y": np.array([2, 3])})  # a step whose x was read at once
    buf.push({"y": np.array([4, 5])}, ((source, [30, 31]),))
    assert source.calls == 0  # nothing converted before the rows are taken
    np.testing.assert_array_equal(buf.take(0)["x"], [20, -1, 60])
    np.testing.assert_array_equal(buf.take(1)["x"], [22, -2, 62])
    assert source.calls == 1  # one conversion for the block, whoever takes first
    buf.push({"y": np.array([6, 7])}, ((source, [40, 41]),))
    np.testing.assert_array_equal(buf.take(1)["x"], [82])
    buf.rewind()
    buf.push({"y": np.array([8, 9])}, ((source, [50, 51]),))
    np.testing.assert_array_equal(buf.take(0)["x"], [100])  # a rewind drops what was captured before it


def _steps(buf, actions, sources):
    """Push one step per action row: its actions and scalars captured (`ActionRows`, `ScalarRows` captures)."""
    for t, a in enumerate(actions):
        buf.push({"y": np.array([t])}, ((sources[0], list(a)), (sources[1], [[0.5 * t], [False], [t == 2], [t > 0]])))


def test_one_env_block_can_leave_its_captures_to_the_writer_process_which_converts_them_the_same():
    """`take(defer=True)`: the captures travel with the block (pickled to the writer process), which converts them to
    the rows the recorder would have made."""
    import pickle

    from simreel.model.fields import FieldSpec
    from simreel.sim.step_rows import ActionRows, ScalarRows

    sources = (ActionRows(1), ScalarRows(1, ["success"], [("success", "success", np.dtype(bool))]))
    actions = np.random.default_rng(0).uniform(-1, 1, (3, 4)).astype(np.float32)
    deferred, converted = StepBuffer(capacity=8, num_envs=1), StepBuffer(capacity=8, num_envs=1)
    _steps(deferred, actions, sources)
    _steps(converted, actions, sources)
    block, expected = deferred.take(0, defer=True), converted.take(0)
    assert set(block.arrays) == {"y"} and len(block.captured) == 2  # nothing converted here
    sent = pickle.loads(pickle.dumps(block)).converted()
    assert set(sent.arrays) == set(expected.arrays) == {"y", "actions", "rewards", "terminated", "truncated", "success"}
    for name, rows in expected.arrays.items():
        assert sent[name].dtype == rows.dtype and np.array_equal(sent[name], rows), name
    np.testing.assert_array_equal(sent["actions"], actions)
    np.testing.assert_array_equal(sent["success"], [False, True, True])
    fields = [FieldSpec("y", "int64", (), False), FieldSpec("actions", "float32", (4,), False)]
    table = fields + [FieldSpec(n, "float32" if n == "rewards" else "bool", (), False) for n in sources[1].names]
    assert set(block.conform(table, episode=0)) == {"y"}  # the captured fields count as there, checked once converted
    with pytest.raises(EpisodeLayoutError, match="rewards not in the recording's layout"):
        block.conform([f for f in table if f.name != "rewards"], episode=0)
    assert deferred.pending(0) == 0 and not deferred._captured  # the next block starts with nothing captured


def test_captures_are_converted_here_where_a_source_missed_a_step_or_there_are_many_envs():
    from simreel.sim.step_rows import ActionRows

    source = ActionRows(1)
    buf = StepBuffer(capacity=4, num_envs=1)
    buf.push({"y": np.array([0])}, ((source, [1.0, 2.0]),))
    buf.push({"y": np.array([1]), "actions": np.array([[3.0, 4.0]], np.float32)})  # a step whose actions came as rows
    block = buf.take(0, defer=True)
    assert block.captured == () and block["actions"].tolist() == [[1.0, 2.0], [3.0, 4.0]]
    two = StepBuffer(capacity=4, num_envs=2)
    two.push({"y": np.array([0, 1])}, ((ActionRows(2), [1.0, 2.0, 3.0, 4.0]),))
    block = two.take(1, defer=True)  # each env's block would convert every env's captures
    assert block.captured == () and block["actions"].tolist() == [[3.0, 4.0]]


def test_a_step_without_a_field_the_first_step_brought_is_refused_and_not_stored():
    """Regression: a step whose observations lost a key left that field's row as it was: rows of an earlier block,
    or np.empty's garbage, recorded as data. Every step must bring the first step's fields, as arrays or through its
    captures' sources (a state read through get_state_dict() once the fast reader cannot: the same fields)."""
    source = _Doubling()
    buf = StepBuffer(capacity=4, num_envs=1)
    buf.push({"x": np.array([1]), "y": np.array([2])})
    buf.push({"y": np.array([3])}, ((source, [5]),))  # x through a source: the same fields
    with pytest.raises(FieldsChanged) as missing:
        buf.push({"y": np.array([4])})
    assert (missing.value.missing, missing.value.new) == (["x"], [])
    with pytest.raises(FieldsChanged) as swapped:  # as many arrays as a good step, one of them new
        buf.push({"x": np.array([6]), "z": np.array([7])})
    assert (swapped.value.missing, swapped.value.new) == (["y"], ["z"])
    assert buf.rows == 2
    buf.push({"x": np.array([8]), "y": np.array([9])})
    block = buf.take(0)
    assert set(block.arrays) == {"x", "y"} and block["x"].tolist() == [1, 10, 8] and block["y"].tolist() == [2, 3, 9]
