"""The per-step scalar fields of a recording — rewards, terminated, truncated, success, fail and the scalar
`info` entries — captured after each step as plain Python lists, and turned into arrays a block at a time by
`simreel.sim.step_rows.ScalarRows`.

`tolist()` copies a tensor's numbers out in one call, so a capture never changes when the env later updates
its tensors in place (ManiSkill's CPU `elapsed_steps` is one such tensor), and Python floats hold float32 and
float64 numbers exactly. Right after a physics step this costs a third of converting each value to numpy and
copying it into the block (`StepBuffer`).
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from simreel.sim.step_rows import ScalarRows, one_per_env

__all__ = ["StepScalars", "scalar_info"]

_SKIPPED_INFO = ("reconfigure",)


def scalar_info(info: dict[str, Any], n: int) -> dict[str, np.ndarray]:
    """Info entries that hold one scalar per env, as (n,) arrays; everything else is left out."""
    out = {}
    for key, value in info.items():
        a = None if key in _SKIPPED_INFO else one_per_env(value, n)
        if a is not None:
            out[key] = a
    return out


def _plain(value: Any) -> Any:
    """`value`'s numbers as Python objects: a copy, also of a list or tuple (a task may change its list in place after
    the step, as ManiSkill does its tensors), `value` itself where it has nothing to copy out (a number, a string), or
    None where it holds no numbers (a dict, any other object: recorded as zeros either way). A capture holds nothing
    else: the recorder's writer process converts it, so it must pickle, and import nothing there (torch, CUDA)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, (numbers.Number, str)):
        return value
    try:
        a = np.asarray(value)
    except Exception:  # noqa: BLE001 - whatever an object raises, it holds no numbers we can record
        return None
    return a.tolist() if a.dtype.kind in "biuf" else None


class StepScalars:
    """Captures a step's scalar fields (`capture`); `rows` converts the captures of a block of steps (a `StepBuffer`
    row source). An info entry the env did not give, or gave as anything but one number per env, is recorded as
    zeros (False), as are success and fail where the task reports neither.

    Args:
        num_envs: the env's parallel envs.
        fields: (name, dtype) of each info field (`info/<key>`) the recording's layout lists.
    """

    def __init__(self, num_envs: int, fields: list[tuple[str, np.dtype]]) -> None:
        self._keys = list(dict.fromkeys(("success", "fail", *(name.removeprefix("info/") for name, _ in fields))))
        named = [(f, f, np.dtype(bool)) for f in ("success", "fail")] + [(n, n.removeprefix("info/"), d) for n, d in fields]
        self.rows = ScalarRows(num_envs, self._keys, named)
        self._absent = np.zeros(num_envs, np.int64)
        """What a step captures (`tolist()`: [0, ...]) for an entry the env's info does not hold: zeros (False) of any
        dtype."""

    def capture(self, reward: Any, terminated: Any, truncated: Any, info: dict[str, Any]) -> list[Any]:
        """This step's scalars, copied out as plain Python numbers and lists."""
        get, absent = info.get, self._absent
        values = (reward, terminated, truncated, *[get(k, absent) for k in self._keys])
        try:  # tensors and arrays, as every ManiSkill task gives them
            return [v.tolist() for v in values]
        except AttributeError:
            return [_plain(v) for v in values]
