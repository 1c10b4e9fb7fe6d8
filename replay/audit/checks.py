"""The comparisons of an audit: two instances of a task that should agree after a restore, and the findings
where they do not (`AuditFinding`, collected in an `AuditReport`).

A `Check` says what is compared (its finding kind), with which tolerances, at which step and why a
difference matters; `compare_states` and `compare_computed` add one finding per key that differs.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.model.components import Tolerances, component_error, components_of
from simreel.model.state_tree import flatten, to_numpy

__all__ = ["AuditFinding", "AuditReport", "Check", "Computed", "compare_states", "compare_computed",
           "computed_now", "differing_attributes", "max_error", "DECLARE"]

DECLARE = (
    "task state not in the state dict — declare it (simreel.authoring.custom_state.CustomStateMixin with "
    "custom_state = (...), or override get_state_dict/set_state_dict)"
)
_ENV_INTERNALS = frozenset({
    "_elapsed_steps", "_episode_seed", "_main_seed", "_last_obs", "_init_raw_obs", "_init_raw_state",
    "_reconfig_counter", "_batched_episode_rng", "_batched_main_rng", "_episode_rng", "_main_rng",
})
"""BaseEnv bookkeeping that differs between two instances by design (seeds, caches)."""


@dataclass
class AuditFinding:
    """One fidelity problem: `kind` (what was checked), `key` (what differs), `detail` (why, and the fix)."""

    kind: str
    key: str
    detail: str
    step: int | None = None
    error: float | None = None
    tolerance: float | None = None
    phase: str = ""
    """Where along a trajectory it showed (``episode 0 of lift.h5, grasped``); empty for the random-action checks."""

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "key": self.key, "detail": self.detail}
        if self.step is not None:
            out["step"] = self.step
        if self.phase:
            out["phase"] = self.phase
        if self.error is not None:
            out["error"] = self.error if math.isfinite(self.error) else "inf"
        if self.tolerance is not None:
            out["tolerance"] = self.tolerance
        return out


@dataclass
class AuditReport:
    env_id: str
    seed: int
    steps: int
    control_mode: str | None = None
    findings: list[AuditFinding] = field(default_factory=list)
    checks: list[str] = field(default_factory=list)
    """What was checked, one line each (also when it passed)."""
    notes: list[str] = field(default_factory=list)
    """Facts worth knowing that are not findings (skipped checks, ManiSkill quirks simreel works around)."""

    @property
    def ok(self) -> bool:
        return not self.findings

    def add(self, finding: AuditFinding) -> None:
        """Keep the first finding per key and check (a key that differs after the restore is not reported
        again for the steps after it: same cause)."""
        check = finding.kind.split("_", 1)[-1]
        for f in self.findings:
            if f.key == finding.key and (f.kind == finding.kind or f.kind.split("_", 1)[-1] == check):
                return
        self.findings.append(finding)

    def to_json(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "env_id": self.env_id,
            "seed": self.seed,
            "steps": self.steps,
            "control_mode": self.control_mode,
            "findings": [f.to_json() for f in self.findings],
            "checks": list(self.checks),
            "notes": list(self.notes),
        }

    def summary(self) -> str:
        lines = [f"audit of {self.env_id} (control mode {self.control_mode}, seed {self.seed}, {self.steps} steps)"]
        lines += [f"  checked: {check}" for check in self.checks]
        lines += [f"  note: {note}" for note in self.notes]
        if self.ok:
            lines.append("no findings: restoring the state dict restores everything the task computes")
            return "\n".join(lines)
        lines.append(f"{len(self.findings)} finding(s):")
        for f in self.findings:
            where = "" if f.step is None else f" [step {f.step}" + (f", {f.phase}]" if f.phase else "]")
            lines.append(f"  {f.kind:<18} {f.key}{where}")
            lines.append(f"  {'':<18} {f.detail}")
        return "\n".join(lines)


@dataclass(frozen=True)
class Check:
    """One comparison: its finding `kind`, the `tolerances`, the `step` it is at (None: no step) and `why` a
    difference is a problem (the end of every finding's detail; for computed values it starts with where they
    were compared, "after restore: ...")."""

    kind: str
    tolerances: Tolerances
    step: int | None = None
    why: str = ""
    phase: str = ""


def max_error(a: Any, b: Any) -> float:
    """The largest difference of two values (inf: shapes differ; 1.0: integers or booleans differ)."""
    a, b = to_numpy(a), to_numpy(b)
    if a.shape != b.shape:
        return math.inf
    if a.dtype.kind in "biu" or b.dtype.kind in "biu":
        return float(np.any(a != b))
    if a.size == 0:
        return 0.0
    return float(component_error(a.reshape(1, -1), b.reshape(1, -1))[0])


def compare_states(report: AuditReport, check: Check, want: Mapping[str, np.ndarray],
                   have: Mapping[str, np.ndarray]) -> None:
    """A finding for every state key that one side lacks, that changed shape, or whose part is off."""
    for key in sorted(set(want) | set(have)):
        finding = AuditFinding(check.kind, f"env_states/{key}", "", step=check.step, phase=check.phase)
        if key not in have or key not in want:
            side = "missing after the restore" if key not in have else "present only after the restore"
            finding.detail = f"state key {key!r} {side}: {check.why}"
            report.add(finding)
        elif want[key].shape != have[key].shape:
            finding.detail = f"shape {want[key].shape} became {have[key].shape}: {check.why}"
            report.add(finding)
        else:
            _compare_parts(report, check, key, want[key], have[key])


def _compare_parts(report: AuditReport, check: Check, key: str, a: np.ndarray, b: np.ndarray) -> None:
    for comp in components_of(key, a.shape[1:]):
        err = float(component_error(a, b, comp)[0])
        tol = check.tolerances[comp.group]
        if err > tol:
            report.add(AuditFinding(check.kind, comp.key, f"{comp.key} off by {err:.3g}: {check.why}",
                                    step=check.step, error=err, tolerance=tol, phase=check.phase))


@dataclass(frozen=True)
class Computed:
    """What a task computes from its state: observations, reward and `evaluate()` info."""

    obs: Any
    reward: Any
    info: Mapping[str, Any]


def computed_now(unwrapped: Any, action: Any) -> Computed:
    """`evaluate()` info, observations and the reward (for `action`) of an env in its current state."""
    info = unwrapped.get_info()
    obs = unwrapped.get_obs(info, unflattened=True)
    return Computed(obs, unwrapped.get_reward(obs=obs, action=action, info=info), info)


def compare_computed(report: AuditReport, check: Check, a: Computed, b: Computed) -> None:
    """A finding for every info entry, observation and the reward that differ between `a` and `b`."""
    for key in sorted(set(a.info) | set(b.info)):
        if key == "reconfigure":
            continue
        if key not in a.info or key not in b.info:
            report.add(AuditFinding(f"{check.kind}_evaluate", f"info/{key}",
                                    f"evaluate()[{key!r}] exists in one instance only {check.why}", step=check.step,
                                    phase=check.phase))
            continue
        err = max_error(a.info[key], b.info[key])
        limit = 0.0 if to_numpy(a.info[key]).dtype.kind in "biu" else check.tolerances["info"]
        if err > limit:
            report.add(AuditFinding(f"{check.kind}_evaluate", f"info/{key}", f"evaluate()[{key!r}] differs {check.why}",
                                    step=check.step, error=err, tolerance=limit, phase=check.phase))
    flat_a = flatten(a.obs) if isinstance(a.obs, Mapping) else {"obs": to_numpy(a.obs)}
    flat_b = flatten(b.obs) if isinstance(b.obs, Mapping) else {"obs": to_numpy(b.obs)}
    for key in sorted(set(flat_a) & set(flat_b)):
        err = max_error(flat_a[key], flat_b[key])
        if err > check.tolerances["obs"]:
            report.add(AuditFinding(f"{check.kind}_obs", f"obs/{key}", f"observation {key!r} differs {check.why}",
                                    step=check.step, error=err, tolerance=check.tolerances["obs"], phase=check.phase))
    err = max_error(a.reward, b.reward)
    if err > check.tolerances["reward"]:
        report.add(AuditFinding(f"{check.kind}_reward", "reward", f"the reward differs {check.why}",
                                step=check.step, error=err, tolerance=check.tolerances["reward"], phase=check.phase))


def differing_attributes(ua: Any, ub: Any, state_keys: Iterable[str]) -> list[str]:
    """Tensor, array, Pose and plain number attributes of the task that hold different values in the two
    instances."""
    import torch

    skip = set(_ENV_INTERNALS) | {k.split("/", 1)[0] for k in state_keys}
    out = []
    for name, va in vars(ua).items():
        if name in skip or name not in vars(ub):
            continue
        vb = vars(ub)[name]
        if isinstance(getattr(va, "raw_pose", None), torch.Tensor):  # a ManiSkill Pose, e.g. a cached goal pose
            va, vb = va.raw_pose, getattr(vb, "raw_pose", None)
        if isinstance(va, torch.Tensor) and isinstance(vb, torch.Tensor):
            if va.shape == vb.shape and not torch.equal(va.detach().cpu(), vb.detach().cpu()):
                out.append(name)
        elif isinstance(va, np.ndarray) and isinstance(vb, np.ndarray) and va.dtype != object:
            if va.shape == vb.shape and not np.array_equal(va, vb):
                out.append(name)
        elif isinstance(va, int | float) and isinstance(vb, int | float) and va != vb:  # bool is an int
            out.append(name)
    return sorted(out)
