"""The per-step scalar fields of a recording — rewards, terminated, truncated, success, fail and the scalar
`info` entries — captured after each step as plain Python lists and turned into arrays a block at a time.

`tolist()` copies a tensor's numbers out in one call, so a capture never changes when the env later updates
its tensors in place (ManiSkill's CPU `elapsed_steps` is one such tensor), and Python floats hold float32 and
float64 numbers exactly. Right after a physics step this costs a third of converting each value to numpy and
copying it into the block (`StepBuffer`).
"""

from __future__ import annotations

from itertools import chain
from typing import Any

import numpy as np

from simreel.state_tree import to_numpy

__all__ = ["StepScalars", "scalar_info"]

_SKIPPED_INFO = ("reconfigure",)
_STEP_RESULTS = ("rewards", "terminated", "truncated")
"""What `env.step` returns besides the observation and info: one number per env, always."""


def scalar_info(info: dict[str, Any], n: int) -> dict[str, np.ndarray]:
    """Info entries that hold one scalar per env, as (n,) arrays; everything else is left out."""
    out = {}
    for key, value in info.items():
        a = None if key in _SKIPPED_INFO else _scalar(value, n)
        if a is not None:
            out[key] = a
    return out


def _scalar(value: Any, n: int) -> np.ndarray | None:
    """`value` as an (n,) numeric array when it holds one scalar per env, else None."""
    if value is None or isinstance(value, dict):
        return None
    a = to_numpy(value)
    if a.ndim == 0:
        a = np.broadcast_to(a, (n,))
    return a if a.shape == (n,) and a.dtype.kind in "biuf" else None


def _plain(value: Any) -> Any:
    """`value`'s numbers as Python objects: a copy, also of a list or tuple (a task may change its list in place after
    the step, as ManiSkill does its tensors), or `value` itself where it has nothing to copy out (a number)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


class StepScalars:
    """Captures a step's scalar fields (`capture`) and converts the captures of a block of steps (`rows`, a
    `StepBuffer` row source). An info entry the env did not give, or gave as anything but one number per env,
    is recorded as zeros (False), as are success and fail where the task reports neither.

    Args:
        num_envs: the env's parallel envs.
        fields: (name, dtype) of each info field (`info/<key>`) the recording's layout lists.
    """

    def __init__(self, num_envs: int, fields: list[tuple[str, np.dtype]]) -> None:
        self._n = num_envs
        self._keys = list(dict.fromkeys(("success", "fail", *(name.removeprefix("info/") for name, _ in fields))))
        named = [(f, f, np.dtype(bool)) for f in ("success", "fail")] + [(n, n.removeprefix("info/"), d) for n, d in fields]
        self._optional = [(name, 3 + self._keys.index(key), dtype) for name, key, dtype in named]
        """(field, where its value sits in a capture, dtype) of each field the env may leave out."""
        self._dtypes = {"rewards": np.dtype(np.float32), "terminated": np.dtype(bool), "truncated": np.dtype(bool)}
        self._absent = np.zeros(num_envs, np.int64)
        """What a step captures (`tolist()`: [0, ...]) for an entry the env's info does not hold: zeros (False) of any
        dtype."""
        self._wide_ints = any(d.kind in "iu" and d.itemsize == 8 for _, d in fields)

    def capture(self, reward: Any, terminated: Any, truncated: Any, info: dict[str, Any]) -> list[Any]:
        """This step's scalars, copied out as plain Python numbers and lists."""
        get, absent = info.get, self._absent
        values = (reward, terminated, truncated, *[get(k, absent) for k in self._keys])
        try:  # tensors and arrays, as every ManiSkill task gives them
            return [v.tolist() for v in values]
        except AttributeError:
            return [_plain(v) for v in values]

    def rows(self, captures: list[list[Any]]) -> dict[str, np.ndarray]:
        """The fields of `len(captures)` steps, each (steps, num_envs)."""
        together = self._all_numeric(captures)
        if together is not None:
            out = {name: together[:, j].astype(self._dtypes[name]) for j, name in enumerate(_STEP_RESULTS)}
            out.update({name: together[:, j].astype(dtype) for name, j, dtype in self._optional})
            return out
        out = {name: self._required(name, [c[j] for c in captures]) for j, name in enumerate(_STEP_RESULTS)}
        for name, j, dtype in self._optional:
            out[name] = self._optional_rows([c[j] for c in captures], dtype)
        return out

    def _all_numeric(self, captures: list[list[Any]]) -> np.ndarray | None:
        """Every capture as one (steps, values, num_envs) float64 array, when each value is one number per env and
        float64 holds them all exactly (no 64-bit integer field; bools, float32 and smaller integers it does).
        One flat list to numpy: numpy takes several times longer to read the same numbers nested."""
        values = list(chain.from_iterable(captures))
        if self._wide_ints or set(map(type, values)) != {list} or set(map(len, values)) != {self._n}:
            return None
        try:
            flat = np.array(list(chain.from_iterable(values)), np.float64)
        except (ValueError, TypeError):  # something that is not a number
            return None
        return flat.reshape(len(captures), -1, self._n) if flat.ndim == 1 else None

    def _required(self, name: str, column: list[Any]) -> np.ndarray:
        dtype = self._dtypes[name]
        fast = self._numeric(column)
        if fast is not None:
            return fast.astype(dtype, copy=False)
        return np.stack([np.asarray(v).astype(dtype).reshape(self._n) for v in column])

    def _optional_rows(self, column: list[Any], dtype: np.dtype) -> np.ndarray:
        fast = self._numeric(column)
        if fast is not None:
            return fast.astype(dtype, copy=False)
        zeros = np.zeros(self._n, dtype)
        return np.stack([zeros if (a := _scalar(v, self._n)) is None else a.astype(dtype) for v in column])

    def _numeric(self, column: list[Any]) -> np.ndarray | None:
        """`column` as a (steps, num_envs) array when every capture is one number per env, else None."""
        try:
            a = np.array(column)
        except ValueError:  # ragged
            return None
        return a if a.shape == (len(column), self._n) and a.dtype.kind in "biuf" else None
