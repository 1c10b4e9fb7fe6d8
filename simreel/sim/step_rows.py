"""Row sources: what turns the captures of a block of steps into the block's arrays, one class per kind of capture.

A recorder copies each step's numbers out as plain Python objects right after the physics step (where every numpy
call costs several times its usual price) and converts a block of steps at once, later
(`simreel.recorders.step_buffer`). These classes do the converting. They hold only numbers and names, so they
pickle: a recorder whose writer runs in a child process sends a block's captures with their sources, and the child
converts them while the env goes on (`simreel.model.blocks.StepBlock.captured`). The child keeps each source it was sent
and is sent only its number after (`simreel.recorders.writer_process.ProcessWriter`), so a source never changes once a
block has used it.

Each is called with the captures of k steps, in step order, and returns each of its fields (`names`) as a
(k, num_envs, ...) array:

- `PackedRows`: PhysX `pack()` byte strings → state leaves (`simreel.sim.state.FastStateReader`)
- `ContactRows`: a step's touching contacts → contact forces (`simreel.sim.contacts.ContactSampler.capture`)
- `ActionRows`: a step's actions as a flat list (`simreel.sim.actions.ActionCheck`) → actions
- `ScalarRows`: a step's rewards, flags and info as Python lists (`simreel.recorders.step_scalars`) → their fields
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from itertools import chain
from typing import Any

import numpy as np

from simreel.model.state_tree import to_numpy

__all__ = ["PackedRows", "ContactRows", "ActionRows", "ScalarRows", "one_per_env", "STEP_RESULTS"]

STEP_RESULTS = ("rewards", "terminated", "truncated")
"""What `env.step` returns besides the observation and info: one number per env, always."""

_ZERO_F32 = np.zeros(1, np.float32).tobytes()


@dataclass(frozen=True, eq=False)
class PackedRows:
    """State leaves from `pack()` byte strings of one env: leaf `key` is float32s `index[a:b]` of a byte string with
    one 0.0 appended (the velocities of kinematic actors), for each (key, a, b) of `slices`; named `prefix` + key."""

    index: np.ndarray
    slices: tuple[tuple[str, int, int], ...]
    prefix: str = ""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.prefix + key for key, _, _ in self.slices)

    def __call__(self, captures: list[bytes]) -> dict[str, np.ndarray]:
        """The leaves of `len(captures)` packed states, each (k, 1, ...) float32: one gather for all of them."""
        flat = self.gather(captures)
        return {self.prefix + key: flat[:, None, a:b] for key, a, b in self.slices}

    def gather(self, captures: list[bytes]) -> np.ndarray:
        """Every leaf's float32s of `len(captures)` packed states, in the order of `slices`: (k, index size)."""
        joined = b"".join(part for packed in captures for part in (packed, _ZERO_F32))
        return np.frombuffer(joined, np.float32).reshape(len(captures), -1)[:, self.index]


@dataclass(frozen=True, eq=False)
class ContactRows:
    """Contact forces of `channels` channels from captured contacts: each step's capture is None (nothing touched a
    channel) or (touching contacts, timestep), a touching contact being (where it adds its impulse: (3 × channel,
    sign) pairs, its points' impulses as [x, y, z] lists)."""

    channels: int
    names: tuple[str, ...] = ("contact_forces",)

    def __call__(self, captures: list[Any]) -> dict[str, np.ndarray]:
        """The (steps, 1, C, 3) float32 forces of `captures`.

        The numbers are numpy's, bit for bit, as the forces were first computed: a contact's points are summed in
        float32 row by row (`_point_sum`), the channels add them up in float64 with ManiSkill's signs, and each is
        divided by the timestep in float64 and rounded to float32. The sums run in Python floats: a step touches a
        few contacts, and numpy calls on arrays of 3 cost more than the arithmetic."""
        size = 3 * self.channels
        sums = array("d", bytes(8 * size * len(captures)))
        for k, capture in enumerate(captures):
            if capture is not None:
                _add_channel_sums(sums, k * size, capture[0])
        impulses = np.frombuffer(sums, np.float64).reshape(len(captures), size)
        timesteps = np.array([1.0 if c is None else c[1] for c in captures], np.float64)
        forces = (impulses / timesteps[:, None]).astype(np.float32)
        return {"contact_forces": forces.reshape(len(captures), 1, self.channels, 3)}


def _add_channel_sums(out: array, base: int, touched: list[tuple[list[tuple[int, float]], list[list[float]]]]) -> None:
    """Add each channel's impulse (x, y, z of channel c at base + 3c, float64) of one step: every touching contact's
    point sum, with its sign."""
    for hits, impulses in touched:
        x, y, z = _point_sum(impulses)
        for at, sign in hits:  # sign * x is exact, and a + (-b) is a - b
            out[base + at] += sign * x
            out[base + at + 1] += sign * y
            out[base + at + 2] += sign * z


def _point_sum(impulses: list[list[float]]) -> tuple[float, float, float]:
    """The impulses of a contact's points summed in float32 row by row, as numpy adds (3,) float32 arrays (and
    `np.sum(axis=0)` sums rows), held in Python floats: the double sum of two float32 values, rounded to float32
    (through `array("f")`, C's conversion), is their float32 sum, since a double has more than 2 × 24 + 2 bits."""
    x, y, z = impulses[0]
    for a, b, c in impulses[1:]:
        x, y, z = array("f", (x + a, y + b, z + c))
    return x, y, z


@dataclass(frozen=True, eq=False)
class ActionRows:
    """Actions of `num_envs` envs from each step's flat list of their numbers (float32, as recordings hold them)."""

    num_envs: int
    names: tuple[str, ...] = ("actions",)

    def __call__(self, captures: list[list[Any]]) -> dict[str, np.ndarray]:
        return {"actions": np.array(captures, np.float32).reshape(len(captures), self.num_envs, -1)}


class ScalarRows:
    """The per-step scalar fields of `num_envs` envs from each step's capture: [reward, terminated, truncated, then
    the value of each of `keys` in the step's info], each a Python list of one number per env (a tensor's
    `tolist()`), or another Python object where the env gave something else. An info entry the env did not give, or
    gave as anything but one number per env, becomes zeros (False) of its field.

    Args:
        num_envs: the env's parallel envs.
        keys: the info keys each capture holds, in order (success and fail first).
        optional: (field, info key, dtype) of each field taken from the info.
    """

    def __init__(self, num_envs: int, keys: list[str], optional: list[tuple[str, str, np.dtype]]) -> None:
        self._n = num_envs
        self._optional = [(name, 3 + keys.index(key), np.dtype(dtype)) for name, key, dtype in optional]
        """(field, where its value sits in a capture, dtype) of each field the env may leave out."""
        self._dtypes = {"rewards": np.dtype(np.float32), "terminated": np.dtype(bool), "truncated": np.dtype(bool)}
        self._wide_ints = any(d.kind in "iu" and d.itemsize == 8 for _, _, d in self._optional)
        """Whether a field is a 64-bit integer, which float64 may not hold exactly (`_all_numeric`)."""
        self.names = (*STEP_RESULTS, *(name for name, _, _ in self._optional))

    def __call__(self, captures: list[list[Any]]) -> dict[str, np.ndarray]:
        """The fields of `len(captures)` steps, each (steps, num_envs)."""
        together = self._all_numeric(captures)
        if together is not None:
            out = {name: together[:, j].astype(self._dtypes[name]) for j, name in enumerate(STEP_RESULTS)}
            out.update({name: together[:, j].astype(dtype) for name, j, dtype in self._optional})
            return out
        out = {name: self._required(name, [c[j] for c in captures]) for j, name in enumerate(STEP_RESULTS)}
        for name, j, dtype in self._optional:
            out[name] = self._optional_rows([c[j] for c in captures], dtype)
        return out

    def field(self, captures: list[list[Any]], name: str) -> np.ndarray:
        """One field taken from the info (`optional`) of `len(captures)` steps, (steps, num_envs)."""
        j, dtype = next((j, dtype) for field, j, dtype in self._optional if field == name)
        return self._optional_rows([c[j] for c in captures], dtype)

    def last_and_any(self, captures: list[list[Any]], name: str, env: int) -> tuple[bool, bool]:
        """Whether field `name` (taken from the info) is true for env `env` at the last of `len(captures)` steps, and
        at any of them: `field`'s answer, read in Python where each step gave that env a bool (no numpy call for a
        recorder's episode end)."""
        j = next(j for field, j, _ in self._optional if field == name)
        column = [c[j] for c in captures]
        if column and all(type(v) is list and len(v) == self._n for v in column):
            flags = [v[env] for v in column]
            if set(map(type, flags)) == {bool}:
                return flags[-1], True in flags
        rows = self.field(captures, name)[:, env]
        return bool(rows[-1]), bool(rows.any())

    def _all_numeric(self, captures: list[list[Any]]) -> np.ndarray | None:
        """Every capture as one (steps, values, num_envs) float64 array, when each value is one number per env and
        float64 holds them all exactly (no 64-bit integer field; bools, float32 and smaller integers it does).
        One flat list to numpy: numpy takes several times longer to read the same numbers nested. Not where a value
        is anything but a number (None, a string): numpy would read None as NaN and parse "1"; `_numeric`, which
        `field` and the rest take, does neither."""
        values = list(chain.from_iterable(captures))
        if self._wide_ints or set(map(type, values)) != {list} or set(map(len, values)) != {self._n}:
            return None
        try:
            flat = np.array(list(chain.from_iterable(values)))
        except (ValueError, TypeError):  # something that is not a number
            return None
        if flat.ndim != 1 or flat.dtype.kind not in "biuf":
            return None
        return flat.astype(np.float64, copy=False).reshape(len(captures), -1, self._n)

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
        return np.stack([zeros if (a := one_per_env(v, self._n)) is None else a.astype(dtype) for v in column])

    def _numeric(self, column: list[Any]) -> np.ndarray | None:
        """`column` as a (steps, num_envs) array when every capture is one number per env, else None."""
        try:
            a = np.array(column)
        except ValueError:  # ragged
            return None
        return a if a.shape == (len(column), self._n) and a.dtype.kind in "biuf" else None


def one_per_env(value: Any, n: int) -> np.ndarray | None:
    """`value` as an (n,) numeric array when it holds one scalar per env (a single number counts for each), else
    None."""
    if value is None or isinstance(value, dict):
        return None
    a = to_numpy(value)
    if a.ndim == 0:
        a = np.broadcast_to(a, (n,))
    return a if a.shape == (n,) and a.dtype.kind in "biuf" else None
