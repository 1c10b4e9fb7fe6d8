"""Policies the `record` command can drive an env with: random, zero, scripted, or user code.

A policy is a callable `policy(env, obs) -> action`, `env` being the gym env as the user holds it and
the action of shape (num_envs, action_dim) or (action_dim,).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from simreel.errors import SimreelError, UsageError

__all__ = ["Policy", "load_policy", "POLICY_HELP", "PolicyCall"]

Policy = Callable[[Any, Any], Any]
POLICY_HELP = "random | zero | scripted (the task's shipped policy) | MODULE:CALLABLE | FILE.py:CALLABLE"


def _random(env: Any, obs: Any) -> Any:
    return env.action_space.sample()


def _zero(env: Any, obs: Any) -> Any:
    return np.zeros(env.action_space.shape, dtype=env.action_space.dtype)


def load_policy(spec: str, env_id: str) -> Policy:
    """Resolve a `--policy` value; user modules must already be importable (see `--import`)."""
    if spec == "random":
        return _random
    if spec == "zero":
        return _zero
    if spec == "scripted":
        from simreel.sim.user_code import import_user_code

        DEFAULT_POLICIES = import_user_code("simreel.tasks.policies").DEFAULT_POLICIES  # noqa: N806
        if env_id not in DEFAULT_POLICIES:
            have = ", ".join(sorted(DEFAULT_POLICIES))
            raise UsageError(f"no scripted policy ships for {env_id}; tasks with one: {have}")
        return DEFAULT_POLICIES[env_id]
    module_spec, sep, attr = spec.rpartition(":")
    if not sep or not module_spec or not attr:
        raise UsageError(f"bad --policy {spec!r}: expected {POLICY_HELP}")
    from simreel.errors import EnvBuildError
    from simreel.sim.user_code import import_user_code

    try:
        module = import_user_code(module_spec)
    except EnvBuildError as e:
        why = str(e).split(": ", 1)[-1]  # import_user_code's message names the --import option
        raise UsageError(f"--policy {spec}: cannot import {module_spec}: {why}") from None
    policy = getattr(module, attr, None)
    if not callable(policy):
        raise UsageError(f"--policy {spec}: {module_spec} has no callable {attr!r}")
    return policy


class PolicyCall:
    """The --policy `spec` as a command calls it: its failures (an exception, `sys.exit`) and, with `check`, actions
    the env cannot take (`simreel.sim.actions.ActionCheck`) become one-line `UsageError`s naming the policy and `where`
    it was asked. (A recorder checks actions itself: `returned` tells its `ActionError` the same way.)"""

    def __init__(self, spec: str, policy: Policy, check: bool = False) -> None:
        self.spec, self._policy, self._check = spec, policy, check

    def __call__(self, env: Any, obs: Any, where: str = "") -> Any:
        at = f" ({where})" if where else ""
        try:
            action = self._policy(env, obs)
        except (SimreelError, KeyboardInterrupt):
            raise
        except SystemExit as e:
            raise UsageError(f"--policy {self.spec} called sys.exit({e.code!r}){at}; a policy returns actions, the "
                             "recording ends by itself") from None
        except Exception as e:  # the policy's own bug: bad input to simreel, not simreel's
            raise UsageError(f"--policy {self.spec} raised {type(e).__name__}: {e}{at}; fix the policy") from None
        if self._check:
            from simreel.sim.actions import ActionCheck

            self.returned(lambda: ActionCheck.for_env(env)(action), where)
        return action

    def returned(self, use: Any, where: str = "") -> Any:
        """`use()` (a step with the policy's action, or its check), an `ActionError` told as what the policy returned."""
        from simreel.errors import ActionError

        try:
            return use()
        except ActionError as e:
            raise UsageError(f"--policy {self.spec} returned {e}" + (f" ({where})" if where else "")) from None
