"""`AuditOptions`: how `audit_task` builds and drives the task — what `simreel audit` takes, each option declared once
(`simreel.options.declare`): the command's flags, their help and the Python checks come from these fields. Light to
import: the CLI builds its parser from it."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from simreel.errors import UsageError
from simreel.model.selection import EpisodeSelection
from simreel.options.checks import function, mapping, parse_json_kwargs, path_text, text, whole
from simreel.options.declare import check_options, documented, option
from simreel.sim.seeds import check_seed_span
from simreel.sim.user_code import IMPORTS, TRUST_IMPORTS, import_specs

__all__ = ["AuditOptions"]


def _trajectory(name: str, value: Any) -> str | None:
    return None if value is None else path_text(name, value, "the recording to audit along, a str or pathlib.Path, "
                                                             "or None")


@documented
@dataclass(frozen=True)
class AuditOptions:
    """How `audit_task` builds and drives the task; `check` refuses values that cannot work, or options that would be
    ignored, whatever the task. The command line's ``--policy`` (a name) becomes `policy` (a callable) and its
    ``--episodes`` either `episodes` (with a policy) or `trajectory_episodes` (with a trajectory)."""

    imports: tuple[str, ...] = option(default_factory=tuple, spec=IMPORTS, check=lambda name, value: import_specs(value))
    trust_recorded_imports: bool = option(False, spec=TRUST_IMPORTS)
    steps: int = option(20, metavar="N", parse=int, help="random steps before the restore (default 20)",
                        check=whole("the number of random steps before the restore, an int >= 1"))
    seed: int = option(0, metavar="S", parse=int, help="seed of the first instance; the second uses S+1",
                       check=whole("the seed of the first instance, an int >= 0"))
    control_mode: str | None = option(
        None, help="ManiSkill control_mode (default: the task's)",
        check=text('a control mode as a string, e.g. "pd_ee_delta_pos", or None (the task\'s)', optional=True))
    obs_mode: str | None = option(
        "state", help="observation mode whose observations are compared (default state)",
        check=text('an observation mode as a string, e.g. "state", or None (the task\'s)', optional=True))
    reward_mode: str | None = option(
        None, help="ManiSkill reward_mode (default: the task's)",
        check=text('a reward mode as a string, e.g. "dense", or None (the task\'s)', optional=True))
    env_kwargs: Mapping[str, Any] = option(
        default_factory=dict, metavar="JSON", parse=parse_json_kwargs, help="extra gym.make kwargs as a JSON object",
        check=mapping('the gym.make arguments as a dict, e.g. {"robot_uids": "panda"}'))
    trajectory: str | None = option(
        None, metavar="REC", check=_trajectory,
        help="also audit along the episodes of this recording (.h5/.mcap), replaying its actions; its env, control "
             "mode and kwargs are the recording's")
    trajectory_episodes: EpisodeSelection | Sequence[int] | None = option(
        None, cli=False, check=lambda name, value: EpisodeSelection.of(value, name=name),
        help="which of its episodes (None: all): an EpisodeSelection (--episodes 0,3-7, walked one index at a time, "
             "so a range past the file's end is refused at the first episode it lacks) or indices")
    policy: Callable[[Any, Any], Any] | None = option(
        None, cli=False, check=function("a callable policy(env, obs) -> action, or None"),
        help="also audit along `episodes` episodes of this policy (policy(env, obs) -> action), seeds seed, seed + 1, "
             "... (the command line's --policy names it)")
    policy_name: str = option("the policy", cli=False, help="what the policy is called in findings",
                              check=text('what the policy is called in findings, a string, e.g. "--policy scripted"'))
    episodes: int = option(1, cli=False, help="the number of the policy's episodes",
                           check=whole("the number of the policy's episodes, an int >= 1"))
    every: int = option(1, metavar="K", parse=int,
                        help="along a trajectory, restore into the second instance after every K-th step (default 1)",
                        check=whole("the number of steps between two restores along a trajectory, an int >= 1"))

    def __post_init__(self) -> None:
        """Check every option (`check_options`), so that a wrong one is a `UsageError` here, naming it and what to
        give, before any env is built: not a raw error inside the audit (``steps="3"``), the env's own error once
        built (``seed=-1``), nor a value taken for another (``imports="x.py"`` as the modules x, ., p, y;
        ``steps=True`` as 1) or ignored (``every=3`` with nothing to audit along); then `check`."""
        check_options(self)
        self.check()

    def check(self) -> None:
        """`UsageError` for values that cannot work, or options that would be ignored, whatever the task."""
        if self.steps < 1:
            raise UsageError(f"--steps must be >= 1, got {self.steps}")
        last = self.seed + max(2, self.episodes - 1)  # the layout check resets with seed + 2; episode k uses seed + k
        check_seed_span(self.seed, last, "audit", "--episodes")
        if self.every < 1 or self.episodes < 1:
            raise UsageError(f"--every and --episodes must be >= 1, got {self.every} and {self.episodes}")
        if self.trajectory is not None and self.policy is not None:
            raise UsageError("audit along a recording (--trajectory) or along a policy (--policy), not both")
        if self.trajectory_episodes is not None and self.trajectory is None:
            raise UsageError("trajectory_episodes picks episodes of the trajectory: give the recording (--trajectory)")
        if self.episodes != 1 and self.policy is None:
            raise UsageError(f"--episodes {self.episodes} is the number of episodes of a policy: give the policy "
                             "(--policy)")
        if self.every != 1 and self.trajectory is None and self.policy is None:
            raise UsageError(f"--every {self.every} restores along a trajectory: give one (--trajectory or --policy)")
