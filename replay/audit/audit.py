"""Audit a task for state-dict fidelity: does restoring its state dict restore everything it computes?

`audit_task(env_id)` drives two instances of the task:

1. ``get_state_dict()`` must return a dict of per-env arrays, and get → set → get must round-trip.
2. Instance A runs ``steps`` random actions from ``reset(seed)``. Instance B gets the same scene (a
   reconfiguring reset with the same seed) but another episode (``reset(seed + 1)``) and a few other
   actions, so everything the state dict does not carry differs between them. A's state dict is then
   restored into B (`simreel.sim.state.restore_state`: task state, controller targets, step count).
3. Everything the task computes from state must now agree: the state dict itself, ``evaluate()`` info,
   observations and the reward. Then both step the same actions and are compared again.
4. The state-dict layout must not depend on the seed (several reconfiguring resets) nor, where a CUDA
   device exists, on ``num_envs``.
5. With a recording (``trajectory``) or a ``policy``: the same restore-and-compare at every step of real
   trajectories, where grasps, success and moving joints happen (`simreel.replay.audit.trajectory`); each
   finding names the step and the phase.

Each disagreement is an `AuditFinding` naming the key and the likely cause, e.g.
``evaluate()['success'] differs after restore: ... task state not in the state dict — declare it``.
The comparisons themselves are `simreel.replay.audit.checks`.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from simreel.errors import EnvBuildError, UsageError
from simreel.model.components import Tolerances
from simreel.model.state_tree import describe_leaf, layout_of, to_numpy
from simreel.options.checks import (
    check_text,
    options_with,
)
from simreel.replay.audit.checks import (
    DECLARE,
    AuditFinding,
    AuditReport,
    Check,
    Computed,
    compare_computed,
    compare_states,
    computed_now,
    differing_attributes,
    max_error,
)
from simreel.replay.audit.options import AuditOptions
from simreel.sim.rebuild import build_with_render_fallback
from simreel.sim.state import read_state, restore_state

__all__ = ["AuditFinding", "AuditReport", "AuditOptions", "audit_task", "FOLLOW_STEPS"]

FOLLOW_STEPS = 5
"""Steps both instances take after the restore, compared step by step."""


def _state(u: Any) -> dict[str, np.ndarray]:
    return {k: np.array(v) for k, v in read_state(u).items()}


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
        self.state_keys: list[str] = []

    def _hint(self, ua: Any, ub: Any) -> str:
        names = differing_attributes(ua, ub, self.state_keys)
        return f"; task attributes that still differ after the restore: {', '.join(names[:5])}" if names else ""

    def _computed_check(self, phase: str, ua: Any, ub: Any, step: int | None) -> Check:
        cause = f"{DECLARE}{self._hint(ua, ub)}"
        if phase == "restore":
            return Check(phase, self.tol_restore, step, f"after restore: {cause}")
        return Check(phase, self.tol_step, step,
                     f"after stepping both: the two instances evolve differently from the same state: {cause}")

    # -- the checks
    def run(self) -> None:
        env_a = self.make()
        env_b = None
        try:
            if not self._check_dict(env_a.unwrapped):
                return
            built = layout_of(read_state(env_a.unwrapped), batched=True)  # as gym.make left it: a recorder's layout
            actions, other = self._actions(env_a)
            saved, elapsed = self._drive(env_a, actions[: self.steps])
            self._roundtrip(env_a.unwrapped, saved, elapsed)
            env_b = self.make()
            self._restore_into_second(env_a.unwrapped, env_b, other, (saved, elapsed), actions[self.steps - 1])
            self._follow(env_a, env_b, actions[self.steps:])
            self._check_layouts(env_a, built)
        finally:
            if env_b is not None:
                env_b.close()
            env_a.close()

    def _check_dict(self, ua: Any) -> bool:
        self.report.control_mode = ua.control_mode
        raw = ua.get_state_dict()
        if not isinstance(raw, Mapping):
            self.report.add(AuditFinding("not_a_dict", "get_state_dict()",
                                         f"get_state_dict() returned {type(raw).__name__}, expected a dict of per-env "
                                         "arrays; return the dict ManiSkill builds, updated with the task's keys"))
            return False
        self.report.checks.append("get_state_dict() returns a dict")
        return True

    def _actions(self, env: Any) -> tuple[list[Any], list[Any]]:
        """The actions of instance A (before the restore, then followed by both) and the other ones of B."""
        space = env.action_space
        space.seed(self.seed)
        return [space.sample() for _ in range(self.steps + FOLLOW_STEPS)], [space.sample() for _ in range(3)]

    def _drive(self, env: Any, actions: list[Any]) -> tuple[dict[str, np.ndarray], int]:
        env.reset(seed=self.seed, options={"reconfigure": True})
        for a in actions:
            env.step(a)
        saved = _state(env.unwrapped)
        self.state_keys = list(saved)
        return saved, int(to_numpy(env.unwrapped._elapsed_steps).reshape(-1)[0])

    def _roundtrip(self, ua: Any, saved: dict[str, np.ndarray], elapsed: int) -> None:
        """1. get -> set -> get on the same instance."""
        restore_state(ua, saved, elapsed_steps=elapsed)
        why = "set_state_dict() then get_state_dict() does not give back the state"
        compare_states(self.report, Check("roundtrip", self.tol_restore, why=why), saved, _state(ua))
        self.report.checks.append("get -> set -> get round-trips")

    def _restore_into_second(self, ua: Any, env_b: Any, other: list[Any], saved_at: tuple[dict[str, np.ndarray], int],
                             last_action: Any) -> None:
        """2. restore into a second instance in another episode of the same scene; compare what it computes."""
        saved, elapsed = saved_at
        ub = env_b.unwrapped
        env_b.reset(seed=self.seed, options={"reconfigure": True})
        _hold_reconfigure(ub)
        env_b.reset(seed=self.seed + 1)
        for a in other:
            env_b.step(a)
        if any(k.startswith("controller/") for k in saved):
            self._check_controller(ub, saved)
        restore_state(ub, saved, elapsed_steps=elapsed)
        why = ("restoring the state dict into another instance does not reproduce it; set_state_dict() must restore "
               "every key get_state_dict() returns")
        compare_states(self.report, Check("restore_state", self.tol_restore, why=why), saved, _state(ub))
        action = _batched(last_action, ua.device)
        compare_computed(self.report, self._computed_check("restore", ua, ub, None), computed_now(ua, action),
                         computed_now(ub, action))
        self.report.checks.append("evaluate(), observations and reward agree after restoring into a second instance "
                                  f"reset with seed {self.seed + 1}")

    def _follow(self, env_a: Any, env_b: Any, actions: list[Any]) -> None:
        """3. step both with the same actions, comparing after each step."""
        ua, ub = env_a.unwrapped, env_b.unwrapped
        why = ("one instance evolves differently after the restore: the state dict misses state that the physics or "
               "the task uses")
        for k, a in enumerate(actions):
            _, rew_a, _, _, info_a = env_a.step(a)
            _, rew_b, _, _, info_b = env_b.step(a)
            step = self.steps + k
            compare_states(self.report, Check("step_state", self.tol_step, step, why), _state(ua), _state(ub))
            compare_computed(self.report, self._computed_check("step", ua, ub, step),
                             Computed(ua.get_obs(info_a, unflattened=True), rew_a, info_a),
                             Computed(ub.get_obs(info_b, unflattened=True), rew_b, info_b))
        self.report.checks.append(f"state, evaluate(), observations and reward agree over {FOLLOW_STEPS} steps after "
                                  "the restore")

    def _check_controller(self, ub: Any, saved: Mapping[str, np.ndarray]) -> None:
        ctrl = {k: v for k, v in saved.items() if k.startswith("controller/")}
        # ManiSkill's own set_state_dict leaves the controller alone; say so once (simreel restores it).
        ub.set_state_dict(_nested_torch(saved, ub.device))
        after_plain = {k: v for k, v in _state(ub).items() if k.startswith("controller/")}
        if any(max_error(ctrl[k], after_plain.get(k, np.full_like(ctrl[k], np.nan))) > 0 for k in ctrl):
            self.report.notes.append(
                "ManiSkill's set_state_dict() ignores the controller state (" + ", ".join(sorted(ctrl)) +
                "); simreel's restore sets it too"
            )
        restore_state(ub, saved)
        after = {k: v for k, v in _state(ub).items() if k.startswith("controller/")}
        for key, value in ctrl.items():
            err = max_error(value, after.get(key, np.full_like(value, np.nan)))
            if err > 0:
                self.report.add(AuditFinding("controller", f"env_states/{key}",
                                             f"controller state {key!r} does not survive a restore (off by {err:.3g}); "
                                             "the controller must accept set_state() with what get_state() returned",
                                             error=err, tolerance=0.0))
        self.report.checks.append("controller state survives a restore (" + ", ".join(sorted(ctrl)) + ")")

    def _check_layouts(self, env: Any, built: Any) -> None:
        """4. the layout does not depend on the seed, nor differs from the layout the env was `built` with (ManiSkill
        resets an env while building it, with a seed of its own; a recorder made then takes that layout), nor, on a
        GPU, depends on num_envs."""
        seeds = [self.seed, self.seed + 1, self.seed + 2]
        states = []
        for s in seeds:
            env.reset(seed=s, options={"reconfigure": True})
            states.append(read_state(env.unwrapped))
        layouts = [layout_of(state, batched=True) for state in states]
        base = layouts[0]
        for s, layout in zip(seeds[1:], layouts[1:], strict=True):
            self._layout_findings("layout_seed", base, layout, f"with seed {self.seed}", f"with seed {s}")
        self._layout_findings("layout_build", built, base, "as gym.make built it", f"after reset(seed={self.seed})")
        self.report.checks.append(f"state-dict layout is the same as built and for seeds {', '.join(map(str, seeds))}")
        self._check_reset_repeats(env, states[0])
        self._check_num_envs(base)

    def _check_reset_repeats(self, env: Any, first: Mapping[str, np.ndarray]) -> None:
        """The same seed gives the same scene and initial state again, after other seeds' resets (`first`: the state
        after the first reset with `self.seed`): a replay starts every episode from its seed, so a reset that draws
        from something the seed does not set (numpy's or Python's global RNG) is reproduced by no replay."""
        env.reset(seed=self.seed, options={"reconfigure": True})
        why = (f"reset(seed={self.seed}) gives another initial state than it gave before: the reset draws from "
               "something the seed does not set (numpy's or Python's global RNG, a counter); draw from the env's "
               "seeded RNGs (self._batched_episode_rng, or torch inside _initialize_episode, which ManiSkill seeds)")
        compare_states(self.report, Check("reset_seed", self.tol_restore, why=why), first, read_state(env.unwrapped))
        self.report.checks.append(f"reset(seed={self.seed}) gives the same initial state again after other seeds")

    def _layout_findings(self, kind: str, a: Any, b: Any, as_a: str, as_b: str) -> None:
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                self.report.add(AuditFinding(
                    kind, f"env_states/{key}",
                    f"the state-dict layout changes: {key} is {describe_leaf(a.get(key))} {as_a} and "
                    f"{describe_leaf(b.get(key))} {as_b}, and one recording needs one layout; register merged views "
                    "with fixed state sizes, with a state_dof bound where joints vary (simreel.authoring.heterogeneous)"))

    def _check_num_envs(self, base: Any) -> None:
        """The layout with num_envs=2 on the GPU sim equals `base`'s; where the GPU sim cannot be built (no CUDA
        device, or SAPIEN's PhysX GPU library missing), the rest of the audit stands and the report says why this
        check did not run."""
        try:
            import torch

            cuda = torch.cuda.is_available()
        except Exception:  # noqa: BLE001 - a broken torch install means no GPU check, not a crash
            cuda = False
        if not cuda:
            self.report.notes.append("num_envs independence not checked: it needs the GPU sim and there is no CUDA device")
            return
        try:
            env = self.make(num_envs=2, sim_backend="physx_cuda")
        except EnvBuildError as exc:
            self.report.notes.append(f"num_envs independence not checked: the GPU sim could not be built ({exc})")
            return
        try:
            env.reset(seed=self.seed)
            layout = layout_of(read_state(env.unwrapped), batched=True)
        finally:
            env.close()
        for key in sorted(set(base) | set(layout)):
            if base.get(key) != layout.get(key):
                self.report.add(AuditFinding(
                    "layout_num_envs", f"env_states/{key}",
                    f"the state-dict layout depends on num_envs: {key} is {describe_leaf(base.get(key))} with "
                    f"num_envs=1 and {describe_leaf(layout.get(key))} with num_envs=2; register merged views "
                    "(simreel.authoring.heterogeneous)"))
        self.report.checks.append("state-dict layout is the same for num_envs=1 (CPU) and num_envs=2 (GPU)")


def _batched(action: Any, device: Any) -> Any:
    """A sampled action as the env's step passes it to get_reward: a (1, ...) tensor, or a dict of them."""
    import torch

    if isinstance(action, Mapping):
        return {k: _batched(v, device) for k, v in action.items()}
    return torch.as_tensor(np.asarray(action), device=device)[None]


def _nested_torch(flat: Mapping[str, np.ndarray], device: Any) -> dict[str, Any]:
    import torch

    from simreel.model.state_tree import unflatten

    return unflatten({k: torch.as_tensor(np.array(v), device=device) for k, v in flat.items()})


def _config(env_id: str | None, opts: AuditOptions) -> tuple[str, Any]:
    """The env id and `EnvConfig` to audit: the recording's with --trajectory (its imports imported), else the options'."""
    from simreel.model.env_config import EnvConfig
    from simreel.sim.user_code import import_user_code, resolve_task_imports

    imports = list(opts.imports)
    if opts.trajectory is None:
        if env_id is None:
            raise UsageError("name the task to audit (ENV_ID), or a recording with --trajectory")
        config = EnvConfig(num_envs=1, obs_mode=opts.obs_mode, control_mode=opts.control_mode,
                           reward_mode=opts.reward_mode, sim_backend="physx_cpu", env_kwargs=dict(opts.env_kwargs))
    else:
        from simreel.formats import open_reader

        with open_reader(opts.trajectory) as reader:
            meta = reader.meta
        if env_id is not None and env_id != meta.env_id:
            raise UsageError(f"--trajectory {opts.trajectory} is a recording of {meta.env_id}, not of {env_id}")
        # the task's code as a replay finds it: an explicit --import wins, else the recorded specs, looked for
        env_id, imports = meta.env_id, resolve_task_imports(meta.imports, explicit=imports, recording=opts.trajectory,
                                                               trust=opts.trust_recorded_imports)
        env_kwargs = {k: v for k, v in meta.env_kwargs.items() if k != "render_mode"}
        config = EnvConfig.from_meta(meta).with_overrides(num_envs=1, obs_mode=opts.obs_mode, sim_backend="physx_cpu",
                                                          env_kwargs=env_kwargs)
    for spec in dict.fromkeys(imports):
        import_user_code(spec)
    return env_id, config


def _trajectories(opts: AuditOptions) -> Any:
    from simreel.replay.audit.trajectory import policy_trajectories, recorded_trajectories

    if opts.trajectory is not None:
        return recorded_trajectories(opts.trajectory, opts.trajectory_episodes)
    seeds = range(opts.seed, opts.seed + opts.episodes)  # one at a time: a huge --episodes N holds no list
    return policy_trajectories(opts.policy, seeds, _POLICY_STEPS, opts.policy_name)


_POLICY_STEPS = 10_000
"""A policy's episode ends when the task terminates or truncates it (its time limit); this only bounds a task without one."""


def audit_task(env_id: str | None, options: AuditOptions | None = None, **overrides: Any) -> AuditReport:
    """Audit task `env_id` for state-dict fidelity (see the module docstring); never raises for a finding. With
    `trajectory` (a recording; `env_id` may then be None) or `policy`, it also audits along real trajectories
    (`simreel.replay.audit.trajectory`).

    `overrides` are `AuditOptions` fields (``audit_task("PickCube-v1", steps=10)``). Raises `UsageError` for bad
    arguments, before any env is built, and `EnvBuildError` when the env cannot be built.
    """
    check_text("env_id", env_id, 'the task\'s env id as a string, e.g. "PickCube-v1", or None (with trajectory: the '
               "recording's)", optional=True)
    opts = options_with(AuditOptions, options, overrides, 'audit_task(env_id, steps=10)')
    from simreel.sim.make import camera_use, make_env

    env_id, config = _config(env_id, opts)
    render = "none" if camera_use(opts.obs_mode, config.env_kwargs.get("render_mode")) is None else "auto"

    def make(**over: Any) -> Any:
        nonlocal render
        env, render = build_with_render_fallback(lambda r: make_env(env_id, config, render_backend=r, **over), render)
        return env

    report = AuditReport(env_id=env_id, seed=opts.seed, steps=opts.steps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _Auditor(report, make, seed=opts.seed, steps=opts.steps).run()
        if opts.trajectory is not None or opts.policy is not None:
            from simreel.replay.audit.trajectory import audit_along

            audit_along(report, make, _trajectories(opts), every=opts.every)
    return report
