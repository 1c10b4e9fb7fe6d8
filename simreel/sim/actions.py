"""The check every action passes before an env steps with it: numeric, of the env's action shape, finite, within
float32 (what recordings hold, as ManiSkill's do), and not a tensor ManiSkill would fail on inside its step.

The recorder runs it at every step (`simreel.recorders.RecordWrapper`), so it is written for speed: a small action is
checked in Python floats (a numpy call right after a physics step costs several times more) and handed back as a
flat list the recorder copies into its block; commands that drive an env with a user's policy (`simreel audit`) run
it so that a bad action is the policy's one-line error rather than a failure inside ManiSkill.
"""

from __future__ import annotations

import contextlib
import math
from typing import Any

import numpy as np

from simreel.errors import ActionError
from simreel.model.state_tree import to_numpy

__all__ = ["ActionCheck"]

_PYTHON_CHECK_MAX = 256
"""Actions of up to this many numbers are checked and copied out in Python floats."""
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_FLOAT32 = np.dtype(np.float32)


class ActionCheck:
    """Checks the actions of env `env_id` (action shape `shape` per env, `num_envs` envs); `ActionError` for one the
    env cannot take or a recording could not hold or replay."""

    def __init__(self, env_id: str, shape: tuple[int, ...], num_envs: int) -> None:
        self.env_id, self.shape, self.num_envs = env_id, shape, num_envs
        self._shapes = {(num_envs, *shape)} | ({shape} if num_envs == 1 else set())
        self._usual_shape = shape if num_envs == 1 and len(shape) == 1 and shape[0] <= _PYTHON_CHECK_MAX else None
        """The shape of the usual action, checked by the shortest path (`__call__`): one env's flat float32 action."""

    @classmethod
    def for_env(cls, env: Any) -> ActionCheck:
        """The check of a built ManiSkill env's actions."""
        u = env.unwrapped
        name = getattr(getattr(u, "spec", None), "id", None) or type(u).__name__
        return cls(name, tuple(u.single_action_space.shape), u.num_envs)

    def __call__(self, action: Any) -> list[Any] | np.ndarray:
        """`action`'s numbers once checked: a small action as a flat list (a copy), a large one as a (num_envs, A)
        float32 array. The usual action, one env's flat float32 numpy array, takes the shortest path: its sum is
        finite exactly where every number is (float32 numbers cannot overflow a float64 sum)."""
        if type(action) is np.ndarray and action.dtype is _FLOAT32 and action.shape == self._usual_shape:
            values = action.tolist()
            if not math.isfinite(sum(values)):
                raise _non_finite(action)
            return values
        return self._checked(action)

    def _checked(self, action: Any) -> list[Any] | np.ndarray:
        """`__call__` for every action but the usual one."""
        a = action if type(action) is np.ndarray else _as_array(action)  # a numpy array: no conversion
        kind = "" if a is None else a.dtype.kind
        if not kind or kind not in "biuf":
            what = f"dtype {action.dtype}" if hasattr(action, "dtype") else f"type {type(action).__name__}"
            raise ActionError(f"an action of {what}; {self.env_id} takes a numeric array of shape {self.shape}")
        wide = a.dtype.itemsize > 4
        if wide and (kind == "u" or a.dtype.itemsize > 8):  # uint64, longdouble: rare, checked only here
            _check_array_dtype(a)
        if a.shape not in self._shapes:
            raise ActionError(f"an action of shape {a.shape}; {self.env_id} takes shape "
                              f"{(self.num_envs, *self.shape) if self.num_envs > 1 else self.shape}")
        if a.size <= _PYTHON_CHECK_MAX:
            values = a.ravel().tolist()
            if kind == "f" and not math.isfinite(sum(values)) and not all(map(math.isfinite, values)):  # a sum may
                raise _non_finite(a)  # overflow where every number is finite
            if wide and kind == "f" and values and max(map(abs, values)) > _FLOAT32_MAX:
                raise _beyond_float32(a)
            return values
        if kind == "f" and not np.isfinite(a).all():
            raise _non_finite(a)
        if wide and kind == "f" and np.abs(a).max() > _FLOAT32_MAX:
            raise _beyond_float32(a)
        return a.astype(np.float32, copy=False).reshape(self.num_envs, -1)


def _as_array(action: Any) -> np.ndarray | None:
    """`action` as a numpy array where it is one ManiSkill takes (a numpy array, np.matrix too, or a tensor numpy can
    hold: not bfloat16), else None; `ActionError` for a tensor ManiSkill would fail on inside its step."""
    if hasattr(action, "detach"):
        _check_tensor(action)
    if isinstance(action, np.ndarray) or hasattr(action, "detach"):
        with contextlib.suppress(TypeError):
            return np.asarray(to_numpy(action))
    return None


_UNCLIPPABLE = ("torch.uint16", "torch.uint32", "torch.uint64")
"""Tensor dtypes torch cannot clamp, as ManiSkill does with every action. Of numpy arrays, only uint64 ones become such
a tensor: ManiSkill 3.0.1 turns uint16 and uint32 arrays into int32 and int64 first (`to_tensor`)."""


def _check_tensor(action: Any) -> None:
    if getattr(action, "requires_grad", False):
        raise ActionError("an action tensor that requires grad, which ManiSkill cannot take (it calls .numpy() on "
                          "it): detach it, or run the policy under torch.no_grad()")
    if getattr(action, "is_meta", False):
        raise ActionError("an action tensor on torch's meta device, which holds no numbers")
    if str(getattr(action, "dtype", "")) in _UNCLIPPABLE:
        raise ActionError(f"an action of dtype {action.dtype}, which ManiSkill cannot clip to the action space")


def _check_array_dtype(a: np.ndarray) -> None:
    """`ActionError` for a numpy array of 8 bytes or more per number that ManiSkill cannot step with: one that becomes
    a tensor torch cannot clamp (`_UNCLIPPABLE`: uint64) or one torch has no dtype for (longdouble)."""
    if f"torch.{a.dtype.name}" in _UNCLIPPABLE:
        raise ActionError(f"an action of dtype {a.dtype}, which ManiSkill cannot clip to the action space; give "
                          "float32 actions")
    if a.dtype.itemsize > 8:
        raise ActionError(f"an action of dtype {a.dtype}, which torch, and so ManiSkill, cannot take; give float32 "
                          "actions")


def _non_finite(a: np.ndarray) -> ActionError:
    flat = a.reshape(-1)
    return ActionError(f"an action holding NaN or infinity ({flat[~np.isfinite(flat)][:3]}); a recording takes "
                       "finite actions only")


def _beyond_float32(a: np.ndarray) -> ActionError:
    flat = np.abs(a.reshape(-1))
    return ActionError(f"an action holding values beyond float32's range ({flat[flat > _FLOAT32_MAX][:3]}), which the "
                       "recording cannot hold: its actions are float32, as ManiSkill's")
