"""Compare a replayed episode with its recording, leaf by leaf, with a tolerance per kind of value.

Pure numpy: the replay room uses it to verify replays, viewers can use it to show where two recordings
part. Every state leaf is split into named components, each of one kind (group) with its own tolerance::

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

Steps: state row 0 (after reset) is reported as ``at="reset"``, step 0; state row t+1 and the rewards,
flags, info and contacts of row t are the outcome of action t, reported as ``at="step"``, step t.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.episode import FLAG_FIELDS, ContactChannel, Episode, StepBlock, field_group

__all__ = [
    "GROUPS",
    "TOLERANCE_MODES",
    "DEFAULT_TOLERANCES",
    "Tolerances",
    "tolerance",
    "Component",
    "components_of",
    "component_error",
    "QUAT_UNIT_TOLERANCE",
    "not_rotations",
    "Divergence",
    "EpisodeComparison",
    "CompareScope",
    "ErrorTable",
    "BlockComparison",
    "compare_episode",
    "VERDICTS",
    "worst_keys",
    "json_number",
    "format_number",
]

GROUPS = ("pos", "quat", "vel", "qpos", "qvel", "controller", "custom", "reward", "info", "contact", "obs", "flag")
"""Kinds of compared values, each with its own absolute tolerance ("flag" is always exact)."""
TOLERANCE_MODES = ("actions", "states", "step", "resync")
"""Modes that have their own default tolerances: the replay modes (`simreel.replay.MODES`) and ``resync``
(``actions`` with ``--resync K``, judged like ``step``)."""
VERDICTS = ("exact", "within_tolerance", "diverged")

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


def _rows(a: np.ndarray) -> np.ndarray:
    """(N, ...) → (N, K) float64."""
    a = np.asarray(a)
    return a.reshape(a.shape[0], int(np.prod(a.shape[1:], dtype=np.int64))).astype(np.float64, copy=False)


def _abs_diff(rec: np.ndarray, rep: np.ndarray) -> np.ndarray:
    """|rec - rep|, 0 where both hold the same value (the same infinity included) or both NaN, inf where only one
    is NaN or the infinities differ."""
    with np.errstate(invalid="ignore"):
        d = np.abs(rec - rep)
    same = (rec == rep) | (np.isnan(rec) & np.isnan(rep))
    d = np.where(same, 0.0, d)
    return np.where(np.isnan(d), np.inf, d)


def component_error(recorded: np.ndarray, replayed: np.ndarray, comp: Component | None = None) -> np.ndarray:
    """Per-row error (N,) of two (N, ...) arrays, over `comp`'s slice of the flattened row (all of it if None)."""
    rec, rep = _rows(recorded), _rows(replayed)
    if comp is not None:
        rec, rep = rec[:, comp.start : comp.stop], rep[:, comp.start : comp.stop]
    if rec.shape[1] == 0:
        return np.zeros(rec.shape[0])
    if comp is not None and comp.quat:
        return _quat_angle(rec, rep)
    return _abs_diff(rec, rep).max(axis=1)


QUAT_UNIT_TOLERANCE = 1e-4
"""How far a quaternion's norm may be from 1 and still be a rotation: PhysX's own test (``PxQuat::isUnit``). Float32
quaternions the simulator writes are within ~1e-7 of 1; a zeroed or scaled one is far outside."""


def not_rotations(q: np.ndarray) -> np.ndarray:
    """Rows of (N, 4) `q` that are no rotation: a norm off 1 by more than `QUAT_UNIT_TOLERANCE` (or NaN)."""
    return _off_unit(np.linalg.norm(q, axis=1))


def _off_unit(norms: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return ~(np.abs(norms - 1.0) <= QUAT_UNIT_TOLERANCE)


def _identical_error(rows: np.ndarray, comp: Component) -> np.ndarray:
    """Per-row error of `comp` where both sides hold `rows`: 0, but inf where a quaternion is no rotation (what
    `component_error` gives there, without comparing anything)."""
    if not comp.quat:
        return np.zeros(rows.shape[0])
    return np.where(not_rotations(_rows(rows)[:, comp.start : comp.stop]), np.inf, 0.0)


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


@dataclass
class Divergence:
    """Where a replay first left its tolerance."""

    step: int
    key: str
    error: float
    tolerance: float
    at: str = "step"
    """"reset": the state right after reset (step is 0); "step": the outcome of action `step`."""

    def to_json(self) -> dict[str, Any]:
        return {"step": self.step, "at": self.at, "key": self.key, "error": json_number(self.error),
                "tolerance": json_number(self.tolerance)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Divergence:
        """The divergence `to_json` wrote ("inf"/"nan" strings back to floats)."""
        return cls(step=int(d["step"]), key=str(d["key"]), error=float(d["error"]), tolerance=float(d["tolerance"]),
                   at=str(d.get("at", "step")))

    def describe(self) -> str:
        where = "after reset" if self.at == "reset" else f"step {self.step}"
        return f"{where}: {self.key} off by {format_number(self.error)} (tolerance {format_number(self.tolerance)})"

    def sentence(self, subject: str) -> str:
        """`describe` said of `subject`: "replay diverges after reset: ..." or "replay diverges at step 11: ..."."""
        return f"{subject} {'' if self.at == 'reset' else 'at '}{self.describe()}"


@dataclass
class EpisodeComparison:
    """The verdict on one replayed episode, and the numbers behind it."""

    verdict: str
    first_divergence: Divergence | None
    max_abs_error: dict[str, float]
    """Key → largest error over all compared steps (flags: 1.0 where they ever differ)."""
    tolerance: dict[str, float]
    """Key → the tolerance it was judged by."""
    diverged_keys: dict[str, int] = field(default_factory=dict)
    """Key → first step at which it left its tolerance."""
    errors: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    """Key → per-row errors (T+1 rows for state/obs keys, T for per-step keys); not serialized."""
    not_compared: list[str] = field(default_factory=list)
    """One line per recorded key that could not be compared and why (an observation the replay lacks, or has in
    another shape): limits of the verdict, which holds only for the keys compared."""

    @property
    def ok(self) -> bool:
        return self.verdict != "diverged"

    def worst(self, n: int = 5) -> list[tuple[str, float, float]]:
        """The n keys with the largest error relative to their tolerance: (key, error, tolerance)."""
        return worst_keys(self.max_abs_error, self.tolerance, n)


def _rows_differ(recorded: np.ndarray, replayed: np.ndarray, steps: int) -> np.ndarray:
    """Per step, 1.0 where any value of that step's row differs, else 0.0 (`steps` rows, none for an episode of no
    steps, whose rows cannot be reshaped by a length to infer)."""
    differs = np.asarray(recorded) != np.asarray(replayed)
    if steps == 0:
        return np.zeros(0)
    return differs.reshape(steps, -1).any(axis=1).astype(np.float64)


def worst_keys(max_abs_error: Mapping[str, float], tolerance: Mapping[str, float],
               n: int) -> list[tuple[str, float, float]]:
    """Up to n keys with a non-zero error, largest error/tolerance first (an error where the tolerance is 0 ranks
    first): (key, error, tolerance). A key without a tolerance counts as tolerance 0."""

    def ratio(k: str) -> float:
        e, t = max_abs_error[k], tolerance.get(k, 0.0)
        return math.inf if (e > 0 and t == 0) else (e / t if t else 0.0)

    keys = sorted((k for k, e in max_abs_error.items() if e > 0), key=ratio, reverse=True)
    return [(k, max_abs_error[k], tolerance.get(k, 0.0)) for k in keys[:n]]


_INFO_NOT_RETURNED = "the replay's info has no such key"
"""Why a recorded info entry was not compared: the replaying task returned it at no step."""

_CATEGORY_ORDER = {"env_states": 0, "obs": 1, "contacts": 2, "info": 3, "rewards": 4}


def _category(key: str) -> int:
    return _CATEGORY_ORDER.get(key.split("/", 1)[0].split("[", 1)[0], 5)


@dataclass(frozen=True)
class CompareScope:
    """What `compare_episode` compares besides states, rewards, flags and info (always compared)."""

    initial: bool = True
    """The state (and observations) right after reset, row 0."""
    obs: bool = True
    """Observations (when both episodes have them with the same shapes)."""
    contacts: bool = True
    """Contact forces (when both episodes have them with the same shape)."""


@dataclass
class ErrorTable:
    """Per-row errors of every compared key, with its tolerance and whether its rows are states (T+1): what
    `compare_episode` fills from two episodes, and what other per-step checks (a control-mode conversion's
    tracking errors) fill with their own keys and groups, to be judged by the same rules (`comparison`)."""

    tolerances: Tolerances
    scope: CompareScope = CompareScope()
    errors: dict[str, np.ndarray] = field(default_factory=dict)
    tol: dict[str, float] = field(default_factory=dict)
    per_state: dict[str, bool] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    """Recorded key → why it was not compared (`not_compared_lines`)."""

    def add(self, key: str, err: np.ndarray, group: str, *, per_state: bool) -> None:
        """Per-row errors `err` of `key`, judged by the tolerance of `group`; `per_state`: T+1 rows (row 0 after
        reset), else T rows (one per step)."""
        if per_state and not self.scope.initial:
            err = err.copy()
            err[0] = 0.0
        self.errors[key] = err
        self.tol[key] = self.tolerances[group]
        self.per_state[key] = per_state

    def states(self, recorded: Mapping[str, np.ndarray], replayed: Mapping[str, np.ndarray]) -> None:
        for path, rec in recorded.items():
            rep = replayed.get(path)
            if rep is None:
                continue
            identical = rec.shape == rep.shape and np.array_equal(rec, rep)  # the common case, ~10x cheaper
            for comp in components_of(path, rec.shape[1:]):
                # a quaternion is checked even where both sides are equal: restoring a zeroed one keeps it zeroed
                err = _identical_error(rec, comp) if identical else component_error(rec, rep, comp)
                self.add(comp.key, err, comp.group, per_state=True)

    def observations(self, recorded: Mapping[str, np.ndarray], replayed: Mapping[str, np.ndarray]) -> None:
        """Each recorded observation key against the replay's; a key the replay lacks or holds in another shape (a
        file whose obs_mode or observation layout is not the env's) is kept in `skipped`, never passed silently."""
        for path, rec in recorded.items():
            rep = replayed.get(path)
            if rep is None or rep.shape != rec.shape:
                self.skipped[f"obs/{path}"] = ("the replay's observation has no such key" if rep is None else
                                               f"{_row_shape(rec)} a row in the file, {_row_shape(rep)} in the replay")
                continue
            self.add(f"obs/{path}", component_error(rec, rep), "flag" if rec.dtype.kind == "b" else "obs",
                     per_state=True)

    def contacts(self, recorded: np.ndarray, replayed: np.ndarray, channels: list[ContactChannel]) -> None:
        diff = _abs_diff(recorded.astype(np.float64), replayed.astype(np.float64))
        per_channel = diff.max(axis=2) if diff.size else np.zeros((recorded.shape[0], 0))
        for c in range(per_channel.shape[1]):
            name = channels[c].name if c < len(channels) else str(c)
            self.add(f"contacts/{name}", per_channel[:, c], "contact", per_state=False)

    def info(self, recorded: Mapping[str, np.ndarray], replayed: Mapping[str, np.ndarray], steps: int) -> None:
        """Each recorded info entry against the replay's; one the replay lacks (a task that no longer returns it) is
        kept in `skipped`, never compared with the zeros a missing entry would read as."""
        for key, rec in recorded.items():
            rep = replayed.get(key)
            if rep is None:
                self.skipped[f"info/{key}"] = _INFO_NOT_RETURNED
                continue
            if rec.dtype.kind in "biu":  # booleans and integers: exactly
                err = _rows_differ(rec, rep, steps)
                self.add(f"info/{key}", err, "flag", per_state=False)
            else:
                self.add(f"info/{key}", component_error(rec, rep), "info", per_state=False)

    def step_fields(self, recorded: Mapping[str, np.ndarray], replayed: Mapping[str, np.ndarray]) -> None:
        """Rewards and flags (flat field name -> rows), where both sides hold them (a file may hold no rewards,
        success or fail)."""
        if recorded.get("rewards") is not None and replayed.get("rewards") is not None:
            self.add("rewards", component_error(recorded["rewards"], replayed["rewards"]), "reward", per_state=False)
        for name in FLAG_FIELDS:
            rec, rep = recorded.get(name), replayed.get(name)
            if rec is not None and rep is not None:
                self.add(name, (np.asarray(rec) != np.asarray(rep)).astype(np.float64), "flag", per_state=False)

    def rows(self, recorded: Mapping[str, np.ndarray], replayed: Mapping[str, np.ndarray], *,
             channels: list[ContactChannel]) -> None:
        """Compare the same rows of two episodes, given as flat fields (`simreel.episode.StepBlock` arrays): a
        reset row (per-state fields only) or a block of steps. Keys only one side has are skipped."""
        self.states(field_group(recorded, "env_states"), field_group(replayed, "env_states"))
        if self.scope.obs:
            self.observations(field_group(recorded, "obs"), field_group(replayed, "obs"))
        rec_f, rep_f = recorded.get("contact_forces"), replayed.get("contact_forces")
        if self.scope.contacts and rec_f is not None and rep_f is not None and rec_f.shape == rep_f.shape:
            self.contacts(rec_f, rep_f, channels)
        actions = recorded.get("actions")
        if actions is not None:
            self.info(field_group(recorded, "info"), field_group(replayed, "info"), len(actions))
        self.step_fields(recorded, replayed)

    def first_bad_row(self, key: str) -> int | None:
        bad = np.flatnonzero(self.errors[key] > self.tol[key])
        if self.per_state[key] and not self.scope.initial:
            bad = bad[bad >= 1]
        return int(bad[0]) if bad.size else None

    def max_errors(self) -> dict[str, float]:
        start = 0 if self.scope.initial else 1
        return {k: float(e[start if self.per_state[k] else 0 :].max()) if e.size else 0.0
                for k, e in self.errors.items()}

    def comparison(self) -> EpisodeComparison:
        """The verdict on every key added: ``diverged`` when one leaves its tolerance (the first divergence is
        the earliest such step, see `compare_episode`), ``exact`` when every error is 0, else
        ``within_tolerance``."""
        max_err = self.max_errors()
        first, diverged = self.first_divergence()
        if first is not None:
            verdict = "diverged"
        elif all(v == 0.0 for v in max_err.values()):
            verdict = "exact"
        else:
            verdict = "within_tolerance"
        return EpisodeComparison(verdict=verdict, first_divergence=first, max_abs_error=max_err, tolerance=self.tol,
                                 diverged_keys=diverged, errors=self.errors,
                                 not_compared=[f"{key} not compared: {why}" for key, why in self.skipped.items()])

    def first_divergence(self) -> tuple[Divergence | None, dict[str, int]]:
        """The earliest value out of tolerance (see `compare_episode`), and each diverged key's first step."""
        diverged: dict[str, int] = {}
        first: Divergence | None = None
        best: tuple[int, int, float] | None = None  # (row-as-step ordering, category, -ratio)
        for key, err in self.errors.items():
            row = self.first_bad_row(key)
            if row is None:
                continue
            offset = 1 if self.per_state[key] else 0
            step = max(row - offset, 0)
            diverged[key] = step
            ratio = math.inf if self.tol[key] == 0 else float(err[row]) / self.tol[key]
            rank = (row if offset else row + 1, _category(key), -ratio)  # reset (state row 0) before step 0
            if best is None or rank < best:
                best = rank
                at = "reset" if (offset and row == 0) else "step"
                first = Divergence(step=step, key=key, error=float(err[row]), tolerance=self.tol[key], at=at)
        return first, diverged


class BlockComparison:
    """Compares a replay with its recording a block of rows at a time (`reset`, then `steps` for each block in
    order): each block's per-row errors are kept (T+1 or T floats per key, the curves explanations read), the
    blocks' arrays are not. `comparison` judges them as `compare_episode` does a whole episode, with the same
    result."""

    def __init__(self, tolerances: Tolerances, *, channels: Iterable[ContactChannel] = (),
                 scope: CompareScope = CompareScope()) -> None:
        self.tolerances = tolerances
        self.channels = list(channels)
        self.scope = scope
        self._parts: dict[str, list[np.ndarray]] = {}
        self._table = ErrorTable(tolerances, scope)

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        """Row 0: the states (and observations) right after the reset."""
        self._add(recorded, replayed)

    def steps(self, recorded: StepBlock, replayed: StepBlock) -> None:
        """The next block of steps (per-state rows: the states after them)."""
        if recorded.rows != replayed.rows:
            raise ValueError(f"a block of {recorded.rows} recorded steps was replayed as {replayed.rows}")
        self._add(recorded, replayed)

    def info_not_returned(self, keys: Iterable[str]) -> None:
        """The recorded info `keys` the replay returned at no step: named as not compared (their replayed rows are the
        zeros they were filled with), whatever the blocks held."""
        self._table.skipped.update({f"info/{key}": _INFO_NOT_RETURNED for key in keys})

    def _add(self, recorded: StepBlock, replayed: StepBlock) -> None:
        part = ErrorTable(self.tolerances, dataclasses.replace(self.scope, initial=True))
        part.rows(recorded.arrays, replayed.arrays, channels=self.channels)
        self._table.skipped.update(part.skipped)
        for key, err in part.errors.items():
            self._parts.setdefault(key, []).append(err)
            self._table.tol[key] = part.tol[key]
            self._table.per_state[key] = part.per_state[key]

    def comparison(self) -> EpisodeComparison:
        table = self._table
        for key, parts in self._parts.items():
            if key in table.skipped:  # not compared in some block: never counted as checked
                table.tol.pop(key, None)
                table.per_state.pop(key, None)
                continue
            err = np.concatenate(parts) if len(parts) > 1 else parts[0]
            if table.per_state[key] and not self.scope.initial:
                err = err.copy()
                err[0] = 0.0
            table.errors[key] = err
        return table.comparison()


def compare_episode(
    recorded: Episode,
    replayed: Episode,
    tolerances: Tolerances,
    *,
    channels: Iterable[ContactChannel] = (),
    scope: CompareScope = CompareScope(),
) -> EpisodeComparison:
    """Compare every state leaf, reward, flag, info entry, contact channel (and observation) of two episodes.

    Both episodes must have the same length. Keys only one side has are skipped (the caller decides
    whether a layout difference is an error); `channels` name the contact channels in keys; `scope` says
    what else to compare. The first divergence is the earliest step at which a value leaves its
    tolerance; at that step state leaves come first, then observations, contacts, info, rewards and
    flags, and within a category the largest error relative to its tolerance wins. The same comparison as a
    `BlockComparison` of the two episodes in one block.
    """
    T = recorded.length
    if replayed.length != T:
        raise ValueError(f"episode {recorded.meta.index}: replay has {replayed.length} steps, recording {T}")
    blocks = BlockComparison(tolerances, channels=channels, scope=scope)
    blocks.reset(recorded.reset_block(), replayed.reset_block())
    blocks.steps(recorded.steps_block(), replayed.steps_block())
    return blocks.comparison()


def _row_shape(a: np.ndarray) -> str:
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
