"""How a state leaf splits into components of one kind each (position, rotation, velocity, joint positions, ...),
the error between two rows of a component, and the tolerance per kind and replay mode; the numbers' formatting in
reports. Pure numpy: the formats (a ManiSkill file's quirks), the verdicts and the viewers share it.

Every state leaf is split into named components, each of one kind (group) with its own tolerance::

    env_states/actors/cube[p]                 position (m)                       group "pos"
    env_states/actors/cube[q]                 orientation, error = rotation angle  group "quat" (rad)
    env_states/actors/cube[v], [w]            linear / angular velocity          group "vel"
    env_states/articulations/panda[root_p]    root pose / velocity as above
    env_states/articulations/panda[qpos]      joint positions                    group "qpos"
    env_states/articulations/panda[qvel]      joint velocities                   group "qvel"
    env_states/controller/arm/target_pose[p]  controller targets                 group "controller"
    env_states/goal_height                    task (custom) state                group "custom"
    rewards                                                                       group "reward"
    terminated truncated success fail          compared exactly                  group "flag"
    info/<key>                                 floats: group "info"; bools and integers exactly ("flag")
    contacts/<channel>                         force (N)                          group "contact"
    obs/<key path>                                                                group "obs"

Quaternions are compared as rotations, so q and -q are equal. An error is the largest absolute
difference over a component's elements (for quaternions: the angle of the relative rotation) at one step.
A quaternion whose norm is off 1 by more than `QUAT_UNIT_TOLERANCE` (0, a scaled one, NaN) is no rotation: its
error is inf on either side, so a file holding one never verifies, even against a replay that holds it too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

GROUPS = ("pos", "quat", "vel", "qpos", "qvel", "controller", "custom", "reward", "info", "contact", "obs", "flag")
"""Kinds of compared values, each with its own absolute tolerance ("flag" is always exact)."""
TOLERANCE_MODES = ("actions", "states", "step", "resync")
"""Modes that have their own default tolerances: the replay modes (`simreel.replay.MODES`) and ``resync``
(``actions`` with ``--resync K``, judged like ``step``)."""

# Defaults per mode, from measurements on ManiSkill 3.0.1's CPU sim (12 recordings: PickCube, StackCube,
# PegInsertionSide, PushCube, RotateValveLevel0, TriFingerRotateCubeLevel0 with random actions; PickCube in
# pd_ee_target_delta_pos and pd_joint_target_delta_pos; simreel's LiftCube, LiftCubeLeaky, HeteroPick,
# HeteroDrawer with their scripted policies):
# - actions: every replay was bit-exact (error 0.0), fresh env or not. The tolerances only leave room for
#   float noise of another CPU/BLAS; a perturbed action shows orders of magnitude above them.
# - states: a restored state read back differs by <= 1.5e-8, recomputed rewards by <= 1.2e-7. Contact
#   forces (and contact-based info such as is_grasped) come from one step simulated from the restored
#   previous state, so they get step mode's contact tolerance.
# - step / resync: a restored state lacks PhysX's contact and solver caches, so one step from it differs
#   from the uninterrupted step: measured max pos 8.6e-4 m, rotation 0.039 rad, body velocity 6.2 (m/s,
#   rad/s: grasped or spinning objects), qpos 6.6e-4, qvel 1.1, contact force 3.5 N, reward 1.2e-3,
#   float info 3.3e-4. Defaults are about 5x those; positions and rotations are the meaningful check here.
#   An observation holds parts of the state (a state observation: qpos, qvel, poses, some tasks' velocities), so it
#   gets the loosest tolerance of the state groups: with obs at 1e-2, a faithful grasp's one-step qvel noise (~1e-2,
#   far within qvel's 5) was called a divergence of obs/state. The states are the check; these modes need them.
DEFAULT_TOLERANCES: dict[str, dict[str, float]] = {
    "actions": {
        "pos": 1e-5, "quat": 1e-4, "vel": 1e-3, "qpos": 1e-5, "qvel": 1e-3, "controller": 1e-5, "custom": 1e-6,
        "reward": 1e-5, "info": 1e-5, "contact": 1e-2, "obs": 1e-5, "flag": 0.0,
    },
    "states": {
        "pos": 1e-6, "quat": 1e-5, "vel": 1e-5, "qpos": 1e-6, "qvel": 1e-5, "controller": 1e-6, "custom": 1e-6,
        "reward": 1e-5, "info": 1e-5, "contact": 20.0, "obs": 1e-5, "flag": 0.0,
    },
    "step": {
        "pos": 5e-3, "quat": 0.2, "vel": 30.0, "qpos": 5e-3, "qvel": 5.0, "controller": 5e-3, "custom": 1e-6,
        "reward": 1e-2, "info": 1e-2, "contact": 20.0, "obs": 30.0, "flag": 0.0,
    },
}
DEFAULT_TOLERANCES["resync"] = dict(DEFAULT_TOLERANCES["step"])


@dataclass(frozen=True)
class Tolerances:
    """Absolute tolerance per group (see `GROUPS`). Build with `Tolerances.for_mode(mode, ...)`. Every value is a
    finite number >= 0 (`tolerance`, `ValueError` otherwise), however the tolerances were built."""

    values: Mapping[str, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", {g: tolerance(v, f"tolerance {g}") for g, v in self.values.items()})

    @classmethod
    def for_mode(
        cls, mode: str, *, atol: float | None = None, groups: Mapping[str, float] | None = None
    ) -> Tolerances:
        """Defaults of `mode`; `atol` replaces every group's tolerance but "flag"; `groups` then overrides single groups."""
        if mode not in DEFAULT_TOLERANCES:
            raise ValueError(f"unknown mode {mode!r}; expected one of {', '.join(DEFAULT_TOLERANCES)}")
        values = dict(DEFAULT_TOLERANCES[mode])
        if atol is not None:
            values = {g: (0.0 if g == "flag" else tolerance(atol, "atol")) for g in values}
        for group, tol in (groups or {}).items():
            if group not in values:
                raise ValueError(f"unknown tolerance group {group!r}; expected one of {', '.join(GROUPS)}")
            values[group] = tolerance(tol, f"tolerance {group}")
        return cls(values)

    def __getitem__(self, group: str) -> float:
        return float(self.values[group])

    def to_json(self) -> dict[str, float]:
        return {g: float(v) for g, v in self.values.items()}

    def overrides(self, mode: str) -> str:
        """The groups whose tolerance is not `mode`'s default, as ``pos 1e-4, quat 0.1`` ("" when none is): what a
        run given ``--atol``/``--tol`` changed, for the messages that name its tolerances."""
        defaults = DEFAULT_TOLERANCES[mode]
        return ", ".join(f"{g} {format_number(v)}" for g, v in self.values.items() if defaults.get(g) != v)


def tolerance(value: Any, what: str) -> float:
    """`value` (a number, or its text as ``--atol`` gives it) as a tolerance: a finite number >= 0, else `ValueError`
    whose message begins with `what`. NaN would pass every comparison (a replay
    that diverged would be called within tolerance) and a negative one fail an exact match; a bool is no number
    (True would be a tolerance of 1)."""
    try:
        number = float(value) if not isinstance(value, (bool, np.bool_)) else None
    except (TypeError, ValueError):
        number = None
    if number is None:
        raise ValueError(f"{what} {value!r} is not a number")
    if not 0 <= number < math.inf:
        raise ValueError(f"{what} {value!r}: a tolerance must be a finite number >= 0")
    return number


@dataclass(frozen=True)
class Component:
    """A named slice of one flat leaf: `key` as reported, `group` for its tolerance, `quat` for rotations."""

    key: str
    group: str
    start: int
    stop: int
    quat: bool = False


def _pose_parts(prefix: str, base: str, group_p: str, group_v: str | None, offset: int = 0) -> list[Component]:
    parts = [
        Component(f"{base}[{prefix}p]", group_p, offset, offset + 3),
        Component(f"{base}[{prefix}q]", "quat", offset + 3, offset + 7, quat=True),
    ]
    if group_v is not None:
        parts += [
            Component(f"{base}[{prefix}v]", group_v, offset + 7, offset + 10),
            Component(f"{base}[{prefix}w]", group_v, offset + 10, offset + 13),
        ]
    return parts


def components_of(path: str, shape: tuple[int, ...], *, prefix: str = "env_states/") -> list[Component]:
    """How the state leaf `path` (per-env `shape`) splits into compared components.

    ``actors/<name>`` (13,): p q v w; ``articulations/<name>`` (13 + 2·DOF,): root p q v w, qpos, qvel;
    ``controller/.../*pose*`` (7,): p q; other ``controller/...``: one component; anything else is task state.
    """
    base = prefix + path
    width = int(np.prod(shape)) if shape else 1
    top = path.split("/", 1)[0]
    if top == "actors" and width == 13:
        return _pose_parts("", base, "pos", "vel")
    if top == "articulations" and width >= 13 and (width - 13) % 2 == 0:
        dof = (width - 13) // 2
        parts = _pose_parts("root_", base, "pos", "vel")
        if dof:
            parts += [Component(f"{base}[qpos]", "qpos", 13, 13 + dof), Component(f"{base}[qvel]", "qvel", 13 + dof, width)]
        return parts
    if top == "controller":
        if width == 7 and "pose" in path.rsplit("/", 1)[-1]:
            return [
                Component(f"{base}[p]", "controller", 0, 3),
                Component(f"{base}[q]", "quat", 3, 7, quat=True),
            ]
        return [Component(base, "controller", 0, width)]
    return [Component(base, "custom", 0, width)]


def _flat(a: np.ndarray) -> np.ndarray:
    """(N, ...) → (N, K), in its own dtype (a view where it can be)."""
    a = np.asarray(a)
    return a.reshape(a.shape[0], int(np.prod(a.shape[1:], dtype=np.int64)))


def _rows(a: np.ndarray) -> np.ndarray:
    """(N, ...) → (N, K) float64."""
    return _flat(a).astype(np.float64, copy=False)


def abs_diff(rec: np.ndarray, rep: np.ndarray) -> np.ndarray:
    """|rec - rep|; inf where either side is not finite (NaN or an infinity), whatever the other holds: no simulated
    quantity is, and a NaN restored into a static or kinematic body reads back as the same NaN, which is no proof
    that the replay reproduces anything."""
    with np.errstate(invalid="ignore"):
        d = np.abs(rec - rep)
    return np.where(np.isfinite(rec) & np.isfinite(rep), d, np.inf)


def component_error(recorded: np.ndarray, replayed: np.ndarray, comp: Component | None = None) -> np.ndarray:
    """Per-row error (N,) of two (N, ...) arrays, over `comp`'s slice of the flattened row (all of it if None)."""
    rec, rep = _rows(recorded), _rows(replayed)
    if comp is not None:
        rec, rep = rec[:, comp.start : comp.stop], rep[:, comp.start : comp.stop]
    if rec.shape[1] == 0:
        return np.zeros(rec.shape[0])
    if comp is not None and comp.quat:
        return _quat_angle(rec, rep)
    return abs_diff(rec, rep).max(axis=1)


QUAT_UNIT_TOLERANCE = 1e-4
"""How far a quaternion's norm may be from 1 and still be a rotation: PhysX's own test (``PxQuat::isUnit``). Float32
quaternions the simulator writes are within ~1e-7 of 1; a zeroed or scaled one is far outside."""


def not_rotations(q: np.ndarray) -> np.ndarray:
    """Rows of (N, 4) `q` that are no rotation: a norm off 1 by more than `QUAT_UNIT_TOLERANCE` (or NaN)."""
    return _off_unit(np.linalg.norm(q, axis=1))


def _off_unit(norms: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return ~(np.abs(norms - 1.0) <= QUAT_UNIT_TOLERANCE)


def identical_error(rows: np.ndarray, comp: Component) -> np.ndarray:
    """Per-row error of `comp` where both sides hold `rows`: 0, but inf where a value is not finite or a quaternion
    is no rotation (what `component_error` gives there, without comparing anything)."""
    part = _flat(rows)[:, comp.start : comp.stop]  # no float64 copy of the leaf: the common case stays cheap
    bad = ~np.isfinite(part).all(axis=1)
    if comp.quat:
        bad |= not_rotations(part.astype(np.float64))
    return np.where(bad, np.inf, 0.0)


def _quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation taking wxyz quaternion a to b, per row; q and -q are the same rotation. inf where
    either is no rotation (`not_rotations`): normalised, a zeroed quaternion would be 0 rad from anything, a scaled
    one 0 rad from the rotation it scales."""
    na = np.linalg.norm(a, axis=1, keepdims=True)
    nb = np.linalg.norm(b, axis=1, keepdims=True)
    same = np.all(a == b, axis=1) | np.all(a == -b, axis=1)
    no_rotation = _off_unit(na[:, 0]) | _off_unit(nb[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        a = a / np.where(na == 0, 1, na)
        b = b / np.where(nb == 0, 1, nb)
        # relative rotation r = conj(a) * b; angle = 2 atan2(|r.xyz|, |r.w|) (stable near 0 and pi)
        aw, ax, ay, az = a.T
        bw, bx, by, bz = b.T
        rw = aw * bw + ax * bx + ay * by + az * bz
        rx = aw * bx - ax * bw - ay * bz + az * by
        ry = aw * by + ax * bz - ay * bw - az * bx
        rz = aw * bz - ax * by + ay * bx - az * bw
        angle = 2.0 * np.arctan2(np.sqrt(rx * rx + ry * ry + rz * rz), np.abs(rw))
    angle = np.where(same, 0.0, angle)
    return np.where(no_rotation | np.isnan(angle), np.inf, angle)




def row_shape(a: np.ndarray) -> str:
    """The shape of one row of `a`, as a limit line names it: ``(8,)``, ``()`` for a scalar."""
    return str(tuple(a.shape[1:]))


def json_number(x: float) -> float | str:
    """JSON has no inf/nan: those become the strings "inf" / "nan"."""
    if math.isfinite(x):
        return float(x)
    return "nan" if math.isnan(x) else "inf"


def format_number(x: float) -> str:
    """An error or tolerance for a report line: ``0``, ``0.00123``, ``inf``."""
    if not math.isfinite(x):
        return str(x)
    if x == 0:
        return "0"
    return f"{x:.3g}"
