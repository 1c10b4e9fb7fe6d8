"""The rows of one sample's windows, and what pads them (pure numpy).

A sample is a step t of an episode of T steps: its observation history is the per-state rows t-h+1 .. t (row t
is the state before step t's action; rows before the reset repeat row 0) and its chunk the per-step rows t .. t+c-1
(the action of step t and those after it; rows past the episode's end are padding). Each window comes with an
``_is_pad`` mask. Actions past the end are padded as ManiSkill's diffusion-policy baseline pads them
(`pad_actions`): in delta and velocity control modes a zero command for every dimension but the last (the arm stays
where it is) and the last action's last dimension (the gripper holds); in absolute modes the last action again."""

from __future__ import annotations

import numpy as np

__all__ = ["history_rows", "chunk_rows", "holds_still_with_zeros", "pads_with_zeros", "pad_actions",
           "pad_action_batch", "window_rows", "ACTION_PADS"]

ACTION_PADS = ("auto", "edge", "hold")
"""How actions past an episode's end are padded: ``auto`` by the control mode (`holds_still_with_zeros`),
``edge`` the last action again, ``hold`` zeros with the last dimension of the last action."""


def history_rows(t: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(row numbers, is_pad) of the `steps` per-state rows up to row `t`: rows before 0 are row 0, padded."""
    rows, is_pad = window_rows(np.array([t]), np.array([t + 1]), steps, per_state=True)
    return rows[0], is_pad[0]


def chunk_rows(t: int, steps: int, length: int) -> tuple[np.ndarray, np.ndarray]:
    """(row numbers, is_pad) of the `steps` per-step rows from row `t` of an episode of `length` steps: rows past
    its last are the last row, padded."""
    rows, is_pad = window_rows(np.array([t]), np.array([length]), steps, per_state=False)
    return rows[0], is_pad[0]


def window_rows(t: np.ndarray, lengths: np.ndarray, steps: int, *, per_state: bool) -> tuple[np.ndarray, np.ndarray]:
    """(row numbers, is_pad), each (len(t), steps), of the windows of samples at steps `t` of episodes of `lengths`
    steps: histories of per-state rows (`per_state`, `history_rows`) or chunks of per-step rows (`chunk_rows`)."""
    if per_state:
        want = t[:, None] + np.arange(1 - steps, 1)
        return np.maximum(want, 0), want < 0
    want = t[:, None] + np.arange(steps)
    last = (lengths - 1)[:, None]
    return np.minimum(want, last), want > last


def holds_still_with_zeros(control_mode: str | None) -> bool:
    """Whether a zero command holds the robot still in `control_mode` (delta and velocity modes: ``pd_joint_delta_pos``,
    ``pd_ee_delta_pose``, ``pd_joint_vel``, ...), as ManiSkill's diffusion-policy baseline decides its padding."""
    return bool(control_mode) and ("delta" in control_mode or "vel" in control_mode)


def pads_with_zeros(control_mode: str | None, how: str = "auto") -> bool:
    """Whether actions past the end are padded with zeros but for the last dimension (`ACTION_PADS`)."""
    return how == "hold" or (how == "auto" and holds_still_with_zeros(control_mode))


def pad_actions(actions: np.ndarray, is_pad: np.ndarray, *, control_mode: str | None, how: str = "auto") -> np.ndarray:
    """`actions` (a chunk, its padded rows repeating the last real action: `chunk_rows`) with the padded rows
    replaced as `how` says (`ACTION_PADS`); unpadded chunks are returned as they are."""
    if not is_pad.any() or not pads_with_zeros(control_mode, how):
        return actions
    return pad_action_batch(actions[None].copy(), is_pad[None], np.array([True]))[0]


def pad_action_batch(actions: np.ndarray, is_pad: np.ndarray, zeros: np.ndarray) -> np.ndarray:
    """`actions` (chunks, (batch, steps, ...), padded rows repeating the last real action), changed in place: the
    padded rows of the chunks where `zeros` (batch,) is True are zero but for their last dimension, which the last
    action's is already (the gripper holds)."""
    arm = actions[..., :-1]
    arm[is_pad & zeros[:, None]] = 0
    return actions
