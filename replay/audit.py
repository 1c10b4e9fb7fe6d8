"""Audit a task for state-dict fidelity: does restoring its state dict restore everything it computes?

`audit_task(env_id)` drives two instances of the task:

1. ``get_state_dict()`` must return a dict of per-env arrays, and get → set → get must round-trip.
2. Instance A runs ``steps`` random actions from ``reset(seed)``. Instance B gets the same scene (a
   reconfiguring reset with the same seed) but another episode (``reset(seed + 1)``) and a few other
   actions, so everything the state dict does not carry differs between them. A's state dict is then
   restored into B (`simreel.replay.restore.restore_state`: task state, controller targets, step count).
3. Everything the task computes from state must now agree: the state dict itself, ``evaluate()`` info,
   observations and the reward. Then both step the same actions and are compared again.
4. The state-dict layout must not depend on the seed (several reconfiguring resets) nor, where a CUDA
   device exists, on ``num_envs``.

Each disagreement is an `AuditFinding` naming the key and the likely cause, e.g.
``evaluate()['success'] differs after restore: ... task state not in the state dict — declare it``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.compare import Tolerances, component_error, components_of
from simreel.errors import UsageError
from simreel.rebuild import build_with_render_fallback
from simreel.replay.restore import restore_state
from simreel.state_tree import describe_leaf, flatten, layout_of, to_numpy

__all__ = ["AuditFinding", "AuditReport", "audit_task", "FOLLOW_STEPS"]

FOLLOW_STEPS = 5
"""Steps both instances take after the restore, compared step by step."""

_DECLARE = (
    "task state not in the state dict — declare it (simreel.custom_state.CustomStateMixin with "
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

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "key": self.key, "detail": self.detail}
        if self.step is not None:
            out["step"] = self.step
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
        for check in self.checks:
            lines.append(f"  checked: {check}")
        for note in self.notes:
            lines.append(f"  note: {note}")
        if self.ok:
            lines.append("no findings: restoring the state dict restores everything the task computes")
        else:
            lines.append(f"{len(self.findings)} finding(s):")
            for f in self.findings:
                where = "" if f.step is None else f" [step {f.step}]"
                lines.append(f"  {f.kind:<18} {f.key}{where}")
                lines.append(f"  {'':<18} {f.detail}")
        return "\n".join(lines)


# ------------------------------------------------------------------------------------------ helpers
def _max_error(a: Any, b: Any) -> float:
    a, b = to_numpy(a), to_numpy(b)
    if a.shape != b.shape:
        return math.inf
    if a.dtype.kind in "biu" or b.dtype.kind in "biu":
        return float(np.any(a != b))
    if a.size == 0:
        return 0.0
    return float(component_error(a.reshape(1, -1), b.reshape(1, -1))[0])


def _differing_attributes(ua: Any, ub: Any, state_keys: Iterable[str]) -> list[str]:
    """Tensor, array and Pose attributes of the task that hold different values in the two instances."""
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
    return sorted(out)


def _state(u: Any) -> dict[str, np.ndarray]:
    return {k: np.array(v) for k, v in flatten(u.get_state_dict()).items()}


def _hold_reconfigure(u: Any) -> None:
    if getattr(u, "reconfiguration_freq", 0) and getattr(u, "_reconfig_counter", 1) == 0:
        u._reconfig_counter = 1


class _Auditor:
    def __init__(self, report: AuditReport, make: Any, *, seed: int, steps: int) -> None:
        self.report = report
        self.make = make
        self.seed = seed
        self.steps = steps
        self.tol_restore = Tolerances.for_mode("states")
        self.tol_step = Tolerances.for_mode("step")

    # -- comparisons
    def _compare_state(self, kind: str, want: Mapping[str, np.ndarray], have: Mapping[str, np.ndarray],
                       tol: Tolerances, step: int | None, why: str) -> None:
        for key in sorted(set(want) | set(have)):
            if key not in have or key not in want:
                side = "missing after the restore" if key not in have else "present only after the restore"
                self.report.add(AuditFinding(kind, f"env_states/{key}", f"state key {key!r} {side}: {why}",
                                             step=step))
                continue
            a, b = want[key], have[key]
            if a.shape != b.shape:
                self.report.add(AuditFinding(kind, f"env_states/{key}",
                                             f"shape {a.shape} became {b.shape}: {why}", step=step))
                continue
            for comp in components_of(key, a.shape[1:]):
                err = float(component_error(a, b, comp)[0])
                if err > tol[comp.group]:
                    self.report.add(AuditFinding(kind, comp.key, f"{comp.key} off by {err:.3g}: {why}", step=step,
                                                 error=err, tolerance=tol[comp.group]))

    def _compare_computed(self, phase: str, ua: Any, ub: Any, action: Any, tol: Tolerances, step: int | None,
                          results: tuple[Any, Any] | None = None) -> None:
        """Compare evaluate() info, observations and reward of the two instances in their current states."""
        if results is None:
            info_a, info_b = ua.get_info(), ub.get_info()
            obs_a = ua.get_obs(info_a, unflattened=True)
            obs_b = ub.get_obs(info_b, unflattened=True)
            rew_a = ua.get_reward(obs=obs_a, action=action, info=info_a)
            rew_b = ub.get_reward(obs=obs_b, action=action, info=info_b)
        else:
            (obs_a, rew_a, info_a), (obs_b, rew_b, info_b) = results
        hint = self._hint(ua, ub)
        cause = f"{_DECLARE}{hint}" if phase == "restore" else (
            f"the two instances evolve differently from the same state: {_DECLARE}{hint}"
        )
        where = "after restore" if phase == "restore" else "after stepping both"
        for key in sorted(set(info_a) | set(info_b)):
            if key == "reconfigure":
                continue
            if key not in info_a or key not in info_b:
                self.report.add(AuditFinding(f"{phase}_evaluate", f"info/{key}",
                                             f"evaluate()[{key!r}] exists in one instance only {where}", step=step))
                continue
            err = _max_error(info_a[key], info_b[key])
            exact = to_numpy(info_a[key]).dtype.kind in "biu"
            limit = 0.0 if exact else tol["info"]
            if err > limit:
                self.report.add(AuditFinding(f"{phase}_evaluate", f"info/{key}",
                                             f"evaluate()[{key!r}] differs {where}: {cause}",
                                             step=step, error=err, tolerance=limit))
        flat_a = flatten(obs_a) if isinstance(obs_a, Mapping) else {"obs": to_numpy(obs_a)}
        flat_b = flatten(obs_b) if isinstance(obs_b, Mapping) else {"obs": to_numpy(obs_b)}
        for key in sorted(set(flat_a) & set(flat_b)):
            err = _max_error(flat_a[key], flat_b[key])
            if err > tol["obs"]:
                self.report.add(AuditFinding(f"{phase}_obs", f"obs/{key}", f"observation {key!r} differs {where}: {cause}",
                                             step=step, error=err, tolerance=tol["obs"]))
        err = _max_error(rew_a, rew_b)
        if err > tol["reward"]:
            self.report.add(AuditFinding(f"{phase}_reward", "reward", f"the reward differs {where}: {cause}",
                                         step=step, error=err, tolerance=tol["reward"]))

    def _hint(self, ua: Any, ub: Any) -> str:
        names = _differing_attributes(ua, ub, self.state_keys)
        if not names:
            return ""
        shown = ", ".join(names[:5])
        return f"; task attributes that still differ after the restore: {shown}"

    # -- the checks
    def run(self) -> None:

        report = self.report
        env_a = self.make()
        env_b = None
        try:
            ua = env_a.unwrapped
            report.control_mode = ua.control_mode
            raw = ua.get_state_dict()
            if not isinstance(raw, Mapping):
                report.add(AuditFinding("not_a_dict", "get_state_dict()",
                                        f"get_state_dict() returned {type(raw).__name__}, expected a dict of per-env "
                                        "arrays; return the dict ManiSkill builds, updated with the task's keys"))
                return
            report.checks.append("get_state_dict() returns a dict")

            space = env_a.action_space
            space.seed(self.seed)
            actions = [space.sample() for _ in range(self.steps + FOLLOW_STEPS)]
            other = [space.sample() for _ in range(3)]

            env_a.reset(seed=self.seed, options={"reconfigure": True})
            for a in actions[: self.steps]:
                env_a.step(a)
            saved = _state(ua)
            self.state_keys = list(saved)
            elapsed = int(to_numpy(ua._elapsed_steps).reshape(-1)[0])

            # 1. get -> set -> get on the same instance
            restore_state(ua, saved, elapsed_steps=elapsed)
            self._compare_state("roundtrip", saved, _state(ua), self.tol_restore, None,
                                "set_state_dict() then get_state_dict() does not give back the state")
            report.checks.append("get -> set -> get round-trips")

            # 2. restore into a second instance in another episode of the same scene
            env_b = self.make()
            ub = env_b.unwrapped
            env_b.reset(seed=self.seed, options={"reconfigure": True})
            _hold_reconfigure(ub)
            env_b.reset(seed=self.seed + 1)
            for a in other:
                env_b.step(a)
            if "controller" in ua.get_state_dict():
                self._check_controller(ua, ub, saved)
            restore_state(ub, saved, elapsed_steps=elapsed)
            self._compare_state("restore_state", saved, _state(ub), self.tol_restore, None,
                                "restoring the state dict into another instance does not reproduce it; "
                                "set_state_dict() must restore every key get_state_dict() returns")
            last = _batched(actions[self.steps - 1], ua.device)
            self._compare_computed("restore", ua, ub, last, self.tol_restore, None)
            report.checks.append("evaluate(), observations and reward agree after restoring into a second instance "
                                 f"reset with seed {self.seed + 1}")

            # 3. step both with the same actions
            for k, a in enumerate(actions[self.steps:]):
                _, rew_a, _, _, info_a = env_a.step(a)
                _, rew_b, _, _, info_b = env_b.step(a)
                step = self.steps + k
                self._compare_state("step_state", _state(ua), _state(ub), self.tol_step, step,
                                    "one instance evolves differently after the restore: the state dict misses "
                                    "state that the physics or the task uses")
                results = ((ua.get_obs(info_a, unflattened=True), rew_a, info_a),
                           (ub.get_obs(info_b, unflattened=True), rew_b, info_b))
                self._compare_computed("step", ua, ub, None, self.tol_step, step, results=results)
            report.checks.append(f"state, evaluate(), observations and reward agree over {FOLLOW_STEPS} steps after "
                                 "the restore")

            # 4. layout independent of the seed (and of num_envs on a GPU)
            self._check_layouts(env_a)
        finally:
            if env_b is not None:
                env_b.close()
            env_a.close()

    def _check_controller(self, ua: Any, ub: Any, saved: Mapping[str, np.ndarray]) -> None:
        ctrl = {k: v for k, v in saved.items() if k.startswith("controller/")}
        # ManiSkill's own set_state_dict leaves the controller alone; say so once (simreel restores it).
        ub.set_state_dict(_nested_torch(saved, ub.device))
        after_plain = {k: v for k, v in _state(ub).items() if k.startswith("controller/")}
        if any(_max_error(ctrl[k], after_plain.get(k, np.full_like(ctrl[k], np.nan))) > 0 for k in ctrl):
            self.report.notes.append(
                "ManiSkill's set_state_dict() ignores the controller state (" + ", ".join(sorted(ctrl)) +
                "); simreel's restore sets it too"
            )
        restore_state(ub, saved)
        after = {k: v for k, v in _state(ub).items() if k.startswith("controller/")}
        for key, value in ctrl.items():
            err = _max_error(value, after.get(key, np.full_like(value, np.nan)))
            if err > 0:
                self.report.add(AuditFinding("controller", f"env_states/{key}",
                                             f"controller state {key!r} does not survive a restore (off by {err:.3g}); "
                                             "the controller must accept set_state() with what get_state() returned",
                                             error=err, tolerance=0.0))
        self.report.checks.append("controller state survives a restore (" + ", ".join(sorted(ctrl)) + ")")

    def _check_layouts(self, env: Any) -> None:
        u = env.unwrapped
        base = None
        seeds = [self.seed, self.seed + 1, self.seed + 2]
        for s in seeds:
            env.reset(seed=s, options={"reconfigure": True})
            layout = layout_of(flatten(u.get_state_dict()), batched=True)
            if base is None:
                base = layout
                continue
            for key in sorted(set(base) | set(layout)):
                if base.get(key) != layout.get(key):
                    self.report.add(AuditFinding(
                        "layout_seed", f"env_states/{key}",
                        f"the state-dict layout depends on the seed: {key} is {describe_leaf(base.get(key))} with "
                        f"seed {self.seed} and {describe_leaf(layout.get(key))} with seed {s}; register merged views "
                        "with fixed state sizes (simreel.heterogeneous)"))
        self.report.checks.append(f"state-dict layout is the same for seeds {', '.join(map(str, seeds))}")
        self._check_num_envs(base)

    def _check_num_envs(self, base: Any) -> None:
        try:
            import torch

            cuda = torch.cuda.is_available()
        except Exception:  # noqa: BLE001 - a broken torch install means no GPU check, not a crash
            cuda = False
        if not cuda:
            self.report.notes.append("num_envs independence not checked: it needs the GPU sim and there is no CUDA device")
            return
        env = self.make(num_envs=2, sim_backend="physx_cuda")
        try:
            env.reset(seed=self.seed)
            layout = layout_of(flatten(env.unwrapped.get_state_dict()), batched=True)
        finally:
            env.close()
        for key in sorted(set(base) | set(layout)):
            if base.get(key) != layout.get(key):
                self.report.add(AuditFinding(
                    "layout_num_envs", f"env_states/{key}",
                    f"the state-dict layout depends on num_envs: {key} is {describe_leaf(base.get(key))} with "
                    f"num_envs=1 and {describe_leaf(layout.get(key))} with num_envs=2; register merged views "
                    "(simreel.heterogeneous)"))
        self.report.checks.append("state-dict layout is the same for num_envs=1 (CPU) and num_envs=2 (GPU)")


def _batched(action: Any, device: Any) -> Any:
    """A sampled action as the env's step passes it to get_reward: a (1, ...) tensor, or a dict of them."""
    import torch

    if isinstance(action, Mapping):
        return {k: _batched(v, device) for k, v in action.items()}
    return torch.as_tensor(np.asarray(action), device=device)[None]


def _nested_torch(flat: Mapping[str, np.ndarray], device: Any) -> dict[str, Any]:
    import torch

    from simreel.state_tree import unflatten

    return unflatten({k: torch.as_tensor(np.array(v), device=device) for k, v in flat.items()})


def audit_task(
    env_id: str,
    *,
    imports: Iterable[str] = (),
    steps: int = 20,
    seed: int = 0,
    control_mode: str | None = None,
    obs_mode: str = "state",
    reward_mode: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> AuditReport:
    """Audit task `env_id` for state-dict fidelity (see the module docstring); never raises for a finding.

    Raises `UsageError` for bad arguments and `EnvBuildError` when the env cannot be built.
    """
    if steps < 1:
        raise UsageError(f"--steps must be >= 1, got {steps}")
    from simreel.envs import camera_use, import_user_code, make_env

    for spec in imports:
        import_user_code(spec)
    render = "none" if camera_use(obs_mode, (env_kwargs or {}).get("render_mode")) is None else "auto"

    def make(**over: Any) -> Any:
        nonlocal render
        kwargs = dict(num_envs=1, obs_mode=obs_mode, control_mode=control_mode, reward_mode=reward_mode,
                      sim_backend="physx_cpu", env_kwargs=env_kwargs)
        kwargs.update(over)
        env, render = build_with_render_fallback(lambda r: make_env(env_id, render_backend=r, **kwargs), render)
        return env

    report = AuditReport(env_id=env_id, seed=seed, steps=steps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _Auditor(report, make, seed=seed, steps=steps).run()
    return report
