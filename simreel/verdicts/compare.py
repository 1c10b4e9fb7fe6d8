"""Compare a replayed episode with its recording, leaf by leaf, with a tolerance per kind of value
(`simreel.model.components`): the first divergence, the largest error per key, the verdict.

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

from simreel.model.blocks import StepBlock
from simreel.model.components import (
    Tolerances,
    abs_diff,
    component_error,
    components_of,
    format_number,
    identical_error,
    json_number,
    row_shape,
)
from simreel.model.episode import Episode
from simreel.model.fields import FLAG_FIELDS, field_group
from simreel.model.meta import ContactChannel

VERDICTS = ("exact", "within_tolerance", "diverged")
"""What a replayed episode is judged: bit for bit, within the tolerances, or not."""


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
                err = identical_error(rec, comp) if identical else component_error(rec, rep, comp)
                self.add(comp.key, err, comp.group, per_state=True)

    def observations(self, recorded: Mapping[str, np.ndarray], replayed: Mapping[str, np.ndarray]) -> None:
        """Each recorded observation key against the replay's; a key the replay lacks or holds in another shape (a
        file whose obs_mode or observation layout is not the env's) is kept in `skipped`, never passed silently."""
        for path, rec in recorded.items():
            rep = replayed.get(path)
            if rep is None or rep.shape != rec.shape:
                self.skipped[f"obs/{path}"] = ("the replay's observation has no such key" if rep is None else
                                               f"{row_shape(rec)} a row in the file, {row_shape(rep)} in the replay")
                continue
            self.add(f"obs/{path}", component_error(rec, rep), "flag" if rec.dtype.kind == "b" else "obs",
                     per_state=True)

    def contacts(self, recorded: np.ndarray, replayed: np.ndarray, channels: list[ContactChannel]) -> None:
        diff = abs_diff(recorded.astype(np.float64), replayed.astype(np.float64))
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
        """Compare the same rows of two episodes, given as flat fields (`simreel.model.blocks.StepBlock` arrays): a
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


