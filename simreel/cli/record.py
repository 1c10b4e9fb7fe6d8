"""`simreel record`: run a policy in a ManiSkill env and record its episodes (.h5 or .mcap)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

from simreel.cli.common import QUIET, EnvOptions, add_env_options, apply_imports, env_options, progress_bar
from simreel.cli.policy_option import POLICY_HELP
from simreel.errors import UsageError
from simreel.io.durable import raise_if_stopped
from simreel.options.declare import add_arguments, check_options, from_arguments, option
from simreel.recorders.options import RecordOptions

__all__ = ["add_parser", "run", "RecordRun"]

_DEFAULT_MAX_STEPS = 200
_STEP_LIMIT = 2**31 - 1
"""The longest time limit ManiSkill can keep: it counts an episode's steps in int32 (beyond, every step ends it)."""


def _episodes(name: str, value: int) -> int:
    if value < 1:
        raise UsageError(f"--episodes must be ≥ 1, got {value}")
    return value


def _max_steps(name: str, value: int | None) -> int | None:
    if value is not None and not 1 <= value <= _STEP_LIMIT:
        raise UsageError(f"--max-steps must be from 1 to {_STEP_LIMIT} (ManiSkill counts steps in 32 bits), got "
                         f"{value}")
    return value


@dataclass(frozen=True)
class RecordRun:
    """What `simreel record` runs, besides `RecordOptions` (what is recorded) and `EnvOptions` (the env): the
    command's own options, each declared once."""

    env_id: str = option("", cli=False, help="the task to record (ENV_ID)")
    output: str = option("", flags=("-o", "--output"), required=True, metavar="OUT", help="output file: .h5 or .mcap")
    episodes: int = option(1, flags=("-n", "--episodes"), parse=int, check=_episodes,
                           help="episodes to record (default 1)")
    seed: int = option(0, parse=int, help="seed of the first episode; episode k uses seed+k")
    policy: str = option("random", help=f"{POLICY_HELP} (default random)")
    max_steps: int | None = option(
        None, parse=int, check=_max_steps,
        help=f"the episodes' time limit in steps, longer or shorter than the task's (default: the task's, else "
             f"{_DEFAULT_MAX_STEPS}); the replay rebuilds the env with it. `max_episode_steps` in --env-kwargs does "
             "the same")
    quiet: bool = option(False, spec=QUIET)

    def __post_init__(self) -> None:
        check_options(self)


def add_parser(sub: Any) -> None:
    p = sub.add_parser("record", help="record episodes of an env to .h5 or .mcap",
                       description="Run a policy in ENV_ID and record every episode with its full state dict.")
    p.add_argument("env_id", metavar="ENV_ID")
    add_arguments(p, RecordRun)
    add_arguments(p, RecordOptions)
    add_env_options(p)
    p.set_defaults(run=run)


def _done(terminated: Any, truncated: Any) -> Any:
    from simreel.model.state_tree import to_numpy

    return to_numpy(terminated).reshape(-1) | to_numpy(truncated).reshape(-1)


def _check_seeds(cmd: RecordRun, env: EnvOptions) -> None:
    """The seeds a run uses fit the simulator's (`check_seed_span`)."""
    from simreel.model.env_config import EnvConfig
    from simreel.sim.seeds import check_seed_span

    num_envs = EnvConfig.num_envs if env.num_envs is None else env.num_envs
    last = cmd.seed + max(cmd.episodes, num_envs) - 1  # the largest seed a run uses (`_record_batched`)
    check_seed_span(cmd.seed, last, "run", "-n")


@dataclass(frozen=True)
class _Limits:
    """How long episodes run: `steps` at most, the env built with time limit `time_limit` (None: the task's own)."""

    steps: int
    time_limit: int | None
    note: str


def _limits(cmd: RecordRun, env: EnvOptions) -> _Limits:
    """The time limit the options ask for (--max-steps, or `max_episode_steps` in --env-kwargs, a gym.make argument
    rather than the task's), and the line that says which limit applies."""
    from simreel.sim.make import time_limit

    registered = time_limit(cmd.env_id)
    asked = env.env_kwargs.pop("max_episode_steps", None)
    if asked is not None and (not isinstance(asked, int) or isinstance(asked, bool) or not 1 <= asked <= _STEP_LIMIT):
        raise UsageError(f"--env-kwargs max_episode_steps must be a whole number from 1 to {_STEP_LIMIT} (ManiSkill "
                         f"counts steps in 32 bits), got {asked!r}")
    if asked is not None and cmd.max_steps is not None and asked != cmd.max_steps:
        raise UsageError(f"--max-steps {cmd.max_steps} and --env-kwargs max_episode_steps {asked} disagree; give one")
    chosen = cmd.max_steps or asked
    if chosen is None:
        if registered is None:
            return _Limits(_DEFAULT_MAX_STEPS, None, f"{cmd.env_id} has no time limit; episodes end after "
                                                     f"{_DEFAULT_MAX_STEPS} steps (--max-steps), or when the task ends them")
        return _Limits(registered, None, f"episodes end at {cmd.env_id}'s time limit of {registered} steps, or "
                                         "earlier when the task ends them")
    if registered is not None and chosen != registered:
        return _Limits(chosen, chosen, f"{cmd.env_id}'s time limit is {registered} steps; this recording sets it to "
                                       f"{chosen} (the recording keeps it, so replay uses it too)")
    return _Limits(chosen, chosen, f"episodes end at the time limit of {chosen} steps, or earlier when the task "
                                   "ends them")


def run(args: argparse.Namespace) -> int:
    cmd = from_arguments(RecordRun, args, env_id=args.env_id)
    env = from_arguments(EnvOptions, args)
    options = from_arguments(RecordOptions, args, command=args.command_line)
    _check_seeds(cmd, env)
    from simreel.formats import check_writable

    check_writable(cmd.output, overwrite=options.overwrite)  # reject what cannot be written before paying for the env
    apply_imports(options.imports)
    from simreel.cli.policy_option import load_policy

    policy = _Policy(cmd.policy, load_policy(cmd.policy, cmd.env_id))
    limits = _limits(cmd, env)
    print(limits.note)
    rec = _recorder(cmd, env, options, limits.time_limit)
    rec.action_space.seed(cmd.seed)  # `--policy random` is then reproducible from --seed
    try:
        if rec.meta.num_envs == 1:
            _record_single(rec, policy, cmd, limits.steps)
        else:
            _record_batched(rec, policy, cmd, limits.steps)
    except BaseException as e:
        from simreel.recorders.record_wrapper import what_stopped

        try:
            rec.stop(what_stopped(e))
        finally:  # also when a second Ctrl-C cuts the stop short: the user must learn where the recording is
            _summary(rec, stopped=True)
        raise
    rec.close()
    _summary(rec)
    return 0


class _Policy:
    """The --policy callable stepping the recorder (`PolicyCall`: one-line errors naming it and when)."""

    def __init__(self, spec: str, policy: Any) -> None:
        from simreel.cli.policy_option import PolicyCall

        self.spec = spec
        self._call = PolicyCall(spec, policy)

    def step(self, rec: Any, obs: Any, where: str) -> Any:
        """Ask the policy for an action and step the recorder with it."""
        action = self._call(rec, obs, where)
        return self._call.returned(lambda: rec.step(action), where)


def _recorder(cmd: RecordRun, env_opts: EnvOptions, options: RecordOptions, time_limit: int | None) -> Any:
    """The env the options ask for, wrapped in the recorder (the env is closed if the recorder refuses)."""
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import EnvConfig, make_env

    config = EnvConfig(**env_options(cmd.env_id, env_opts), env_kwargs=env_opts.env_kwargs,
                       max_episode_steps=time_limit)
    env = make_env(cmd.env_id, config)
    try:
        return RecordWrapper(env, cmd.output, options)
    except BaseException:
        env.close()
        raise


def _progress(cmd: RecordRun) -> Any:
    return progress_bar(quiet=cmd.quiet, total=cmd.episodes, unit="ep", desc=f"record {cmd.env_id}")


def _record_single(rec: Any, policy: _Policy, cmd: RecordRun, max_steps: int) -> None:
    with _progress(cmd) as bar:
        for k in range(cmd.episodes):
            obs, _ = rec.reset(seed=cmd.seed + k)
            for t in range(max_steps):
                raise_if_stopped()
                obs, _, terminated, truncated, _ = policy.step(rec, obs, f"episode {k}, step {t}")
                if _done(terminated, truncated).any():
                    break
            bar.update()


def _record_batched(rec: Any, policy: _Policy, cmd: RecordRun, max_steps: int) -> None:
    """N parallel envs running episodes k = 0, 1, ... in the order they start, episode k with seed S+k. An env whose
    episode ends is reset alone (a partial reset: its episode is committed and the next one starts there) while it
    runs one of the `--episodes` wanted; an episode started past those (a reset must start one) gets seed S, is left
    running when it ends, and is dropped at the end: exactly the episodes wanted are recorded, with their seeds."""
    import numpy as np

    n, wanted = rec.meta.num_envs, cmd.episodes
    order = np.arange(n)  # the start order of each env's running episode
    obs, _ = rec.reset(seed=[cmd.seed + i for i in range(n)])
    started, steps = n, np.zeros(n, dtype=np.int64)
    with _progress(cmd) as bar:
        while len(rec.episodes_committed) < wanted:
            raise_if_stopped()
            obs, _, terminated, truncated, _ = policy.step(rec, obs, f"after {len(rec.episodes_committed)} episodes")
            steps += 1
            done = (_done(terminated, truncated) | (steps >= max_steps)) & (order < wanted)
            if done.any():
                idx = np.flatnonzero(done)
                before = len(rec.episodes_committed)
                new = np.arange(started, started + len(idx))
                seeds = [cmd.seed + int(k) if k < wanted else cmd.seed for k in new]
                obs, _ = rec.reset(seed=seeds, options={"env_idx": idx})
                order[idx], started, steps[idx] = new, started + len(idx), 0
                bar.update(len(rec.episodes_committed) - before)
    rec.discard_running()


def _summary(rec: Any, stopped: bool = False) -> None:
    """What the file holds; for a recording stopped before it was complete, also the episode it cut short and, when
    it was to replace an old file, where it is instead (the error's own line follows, on stderr)."""
    from simreel.io.staging import side_folder

    eps = rec.episodes_committed
    steps = sum(e.length for e in eps)
    succ = sum(1 for e in eps if e.success)
    if not stopped:
        size = rec.path.stat().st_size if rec.path.exists() else 0
        print(f"recorded {len(eps)} episode(s), {steps} steps, {succ} successful, to {rec.path} ({size / 1024:.0f} KiB)")
        return
    cut = [e.index for e in eps if any(n.startswith("cut short:") for n in e.notes)]
    staged = side_folder(rec.path) / rec.path.name
    where = (f"in {staged}, beside {rec.path}, which is unchanged (the new recording replaces it only once complete)"
             if staged.is_file() else f"in {rec.path}")
    print(f"stopped: {len(eps)} episode(s), {steps} steps, {succ} successful, {where}"
          + (f"; episode {cut[0]} was cut short (noted in the file)" if cut else ""), flush=True)
