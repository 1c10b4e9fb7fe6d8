"""How far off one step is: the key of a comparison furthest out of its tolerance at a step, or the largest
difference between two states (`Worst`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.model.components import Tolerances, component_error, components_of, format_number
from simreel.verdicts.compare import EpisodeComparison
from simreel.verdicts.divergence import compares_states

__all__ = ["Worst", "worst_at", "state_difference", "COMPUTED", "listed"]

COMPUTED = ("info/", "rewards", "obs/", "terminated", "truncated", "success", "fail")
"""Keys of what a task computes from its state (not the physics: state leaves and contact forces)."""


@dataclass(frozen=True)
class Worst:
    """The key furthest out of (or closest to) its tolerance at one step of a comparison, or between two states
    (step -1: the reset)."""

    step: int
    key: str
    error: float
    tolerance: float
    judged_by: str = "step tolerance"
    """What `tolerance` is: step mode's tolerance, or a share of the replay's divergence
    (`simreel.replay.explain.one_step.SHARE_OF_DIVERGENCE`)."""

    @property
    def ratio(self) -> float:
        """The error in units of its tolerance: above 1 is out of tolerance; any error beyond a zero tolerance is."""
        if self.error == 0:
            return 0.0
        return math.inf if self.tolerance == 0 else self.error / self.tolerance

    def describe(self) -> str:
        """One step's worst key, with the step tolerance it is judged by."""
        return f"{self.key} off by {format_number(self.error)} ({self.judged_by} {format_number(self.tolerance)})"

    def describe_states(self) -> str:
        """Two states' largest difference, or that they are identical."""
        if self.error == 0:
            return "identical"
        return f"{self.key} off by {format_number(self.error)}"


def worst_at(cmp: EpisodeComparison, step: int, *, only: str | tuple[str, ...] = "") -> Worst:
    """The key of `cmp` furthest out of its tolerance at `step`, among the keys starting with `only` (all: "").

    Observations are left out where the state is compared: they are computed from it, and one step after a restore
    their velocity entries carry the same cache noise as the state's velocities, which step mode's observation
    tolerance is not made for."""
    best = Worst(step, "", 0.0, 1.0)
    has_states = compares_states(cmp)
    for key, err in cmp.errors.items():
        per_state = key.startswith(("env_states/", "obs/"))
        if not key.startswith(only) or (has_states and key.startswith("obs/")):
            continue
        row = step + 1 if per_state else step
        if not 0 <= row < len(err):
            continue
        cand = Worst(step, key, float(err[row]), float(cmp.tolerance[key]))
        if cand.ratio > best.ratio:
            best = cand
    return best


def state_difference(a: dict[str, Any], b: dict[str, Any], tol: Tolerances) -> Worst:
    """The largest difference (relative to `tol`) between two flat states (key path → (1, ...) arrays)."""
    worst = Worst(-1, "", 0.0, 1.0)
    for path in sorted(set(a) & set(b)):
        x, y = np.asarray(a[path]), np.asarray(b[path])
        if x.shape != y.shape:
            return Worst(-1, f"env_states/{path}", math.inf, 0.0)
        for comp in components_of(path, x.shape[1:]):
            err = float(component_error(x, y, comp)[0])
            cand = Worst(-1, comp.key, err, tol[comp.group])
            if cand.ratio > worst.ratio:
                worst = cand
    return worst


def listed(items: list[Any]) -> str:
    return ", ".join(map(str, items))
