"""The rows of a sample's windows and the padding of actions past an episode's end."""

from __future__ import annotations

import numpy as np
import pytest

from simreel.training.windows import chunk_rows, history_rows, holds_still_with_zeros, pad_actions


def test_a_history_repeats_row_0_before_the_reset():
    rows, pad = history_rows(1, 4)
    assert rows.tolist() == [0, 0, 0, 1] and pad.tolist() == [True, True, False, False]
    rows, pad = history_rows(7, 2)
    assert rows.tolist() == [6, 7] and not pad.any()


def test_a_chunk_repeats_the_last_row_past_the_end():
    rows, pad = chunk_rows(8, 4, 10)
    assert rows.tolist() == [8, 9, 9, 9] and pad.tolist() == [False, False, True, True]


@pytest.mark.parametrize(("mode", "zeros"), [("pd_joint_delta_pos", True), ("pd_ee_delta_pose", True),
                                             ("pd_joint_vel", True), ("pd_joint_pos", False), ("pd_ee_pose", False),
                                             (None, False)])
def test_which_control_modes_hold_still_with_zeros(mode, zeros):
    assert holds_still_with_zeros(mode) is zeros


def test_padded_actions_by_mode():
    actions = np.array([[0.1, 0.2, 1.0], [0.3, 0.4, -1.0], [0.3, 0.4, -1.0]], dtype=np.float32)
    is_pad = np.array([False, False, True])
    held = pad_actions(actions, is_pad, control_mode="pd_joint_delta_pos")
    assert held.tolist() == [[pytest.approx(0.1), pytest.approx(0.2), 1.0], [pytest.approx(0.3), pytest.approx(0.4),
                                                                             -1.0], [0.0, 0.0, -1.0]]
    assert pad_actions(actions, is_pad, control_mode="pd_joint_pos") is actions
    assert pad_actions(actions, is_pad, control_mode="pd_joint_delta_pos", how="edge") is actions
    assert pad_actions(actions, is_pad, control_mode="pd_joint_pos", how="hold")[2].tolist() == [0.0, 0.0, -1.0]
    assert actions[2].tolist() == [pytest.approx(0.3), pytest.approx(0.4), -1.0]  # the input is left as it was
