"""`simreel record`: run a policy in a ManiSkill env and record its episodes (.h5 or .mcap)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

from simreel.cli.common import GivenOnce, add_env_options, apply_imports, env_options, progress_bar
from simreel.cli.policy_option import POLICY_HELP
from simreel.errors import UsageError
from simreel.io.durable import raise_if_stopped

__all__ = ["add_parser", "run"]

_DEFAULT_MAX_STEPS = 200
_STEP_LIMIT = 2**31 - 1
"""The longest time limit ManiSkill can keep: it counts an episode's steps in int32 (beyond, every step ends it)."""


def add_parser(sub: Any) -> None:
    p = sub.add_parser("record", help="record episodes of an env to .h5 or .mcap",
                       description="Run a policy in ENV_ID and record every episode with its full state dict.")
    p.add_argument("env_id", metavar="ENV_ID")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output file: .h5 or .mcap")
    p.add_argument("-n", "--episodes", type=int, default=1, help="episodes to record (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode; episode k uses seed+k")
    p.add_argument("--policy", default="random", help=f"{POLICY_HELP} (default random)")
    p.add_argument("--max-steps", type=int, default=None,
                   help="the episodes' time limit in steps, longer or shorter than the task's (default: the task's, "
                        f"else {_DEFAULT_MAX_STEPS}); the replay rebuilds the env with it. `max_episode_steps` in "
                        "--env-kwargs does the same")
    p.add_argument("--contacts", action=GivenOnce, default="auto", metavar="auto|none|A:B,...",
                   help="contact channels: auto (default), none, or pairs like panda/panda_leftfinger:cube")
    p.add_argument("--record-obs", action="store_true", help="also record observations")
    p.add_argument("--poses", action=argparse.BooleanOptionalAction, default=None,
                   help="record world poses of every body and link (default: on for .mcap, off for .h5)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_env_options(p)
    p.set_defaults(run=run)


def _done(terminated: Any, truncated: Any) -> Any:
    from simreel.model.state_tree import to_numpy

    return to_numpy(terminated).reshape(-1) | to_numpy(truncated).reshape(-1)


def _check_counts(args: argparse.Namespace) -> None:
    if args.episodes < 1:
        raise UsageError(f"--episodes must be ≥ 1, got {args.episodes}")
    if args.max_steps is not None and not 1 <= args.max_steps <= _STEP_LIMIT:
        raise UsageError(f"--max-steps must be from 1 to {_STEP_LIMIT} (ManiSkill counts steps in 32 bits), got "
                         f"{args.max_steps}")
    from simreel.model.env_config import EnvConfig

    num_envs = EnvConfig.num_envs if args.num_envs is None else args.num_envs
    if num_envs < 1:
        raise UsageError(f"--num-envs must be ≥ 1, got {num_envs}")
    from simreel.sim.seeds import check_seed_span

    last = args.seed + max(args.episodes, num_envs) - 1  # the largest seed a run uses (`_record_batched`)
    check_seed_span(args.seed, last, "run", "-n")


@dataclass(frozen=True)
class _Limits:
    """How long episodes run: `steps` at most, the env built with time limit `time_limit` (None: the task's own)."""

    steps: int
    time_limit: int | None
    note: str


def _limits(args: argparse.Namespace) -> _Limits:
    """The time limit the options ask for (--max-steps, or `max_episode_steps` in --env-kwargs, a gym.make argument
    rather than the task's), and the line that says which limit applies."""
    from simreel.sim.make import time_limit

    registered = time_limit(args.env_id)
    asked = args.env_kwargs.pop("max_episode_steps", None)
    if asked is not None and (not isinstance(asked, int) or isinstance(asked, bool) or not 1 <= asked <= _STEP_LIMIT):
        raise UsageError(f"--env-kwargs max_episode_steps must be a whole number from 1 to {_STEP_LIMIT} (ManiSkill "
                         f"counts steps in 32 bits), got {asked!r}")
    if asked is not None and args.max_steps is not None and asked != args.max_steps:
        raise UsageError(f"--max-steps {args.max_steps} and --env-kwargs max_episode_steps {asked} disagree; give one")
    chosen = args.max_steps or asked
    if chosen is None:
        if registered is None:
            return _Limits(_DEFAULT_MAX_STEPS, None, f"{args.env_id} has no time limit; episodes end after "
                                                     f"{_DEFAULT_MAX_STEPS} steps (--max-steps), or when the task ends them")
        return _Limits(registered, None, f"episodes end at {args.env_id}'s time limit of {registered} steps, or "
                                         "earlier when the task ends them")
    if registered is not None and chosen != registered:
        return _Limits(chosen, chosen, f"{args.env_id}'s time limit is {registered} steps; this recording sets it to "
                                       f"{chosen} (the recording keeps it, so replay uses it too)")
    return _Limits(chosen, chosen, f"episodes end at the time limit of {chosen} steps, or earlier when the task "
                                   "ends them")


def run(args: argparse.Namespace) -> int:
    _check_counts(args)
    from simreel.formats import check_writable

    check_writable(args.output, overwrite=args.overwrite)  # reject what cannot be written before paying for the env
    apply_imports(args.imports)
    from simreel.cli.policy_option import load_policy

    policy = _Policy(args.policy, load_policy(args.policy, args.env_id))
    limits = _limits(args)
    print(limits.note)
    rec = _recorder(args, limits.time_limit)
    rec.action_space.seed(args.seed)  # `--policy random` is then reproducible from --seed
    try:
        if rec.meta.num_envs == 1:
            _record_single(rec, policy, args, limits.steps)
        else:
            _record_batched(rec, policy, args, limits.steps)
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


def _recorder(args: argparse.Namespace, time_limit: int | None) -> Any:
    """The env the options ask for, wrapped in the recorder (the env is closed if the recorder refuses)."""
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import EnvConfig, make_env

    config = EnvConfig(**env_options(args), env_kwargs=args.env_kwargs, max_episode_steps=time_limit)
    env = make_env(args.env_id, config)
    try:
        return RecordWrapper(env, args.output, contacts=args.contacts, record_obs=args.record_obs, poses=args.poses,
                             overwrite=args.overwrite, imports=tuple(args.imports), command=args.command_line)
    except BaseException:
        env.close()
        raise


def _progress(args: argparse.Namespace) -> Any:
    return progress_bar(quiet=args.quiet, total=args.episodes, unit="ep", desc=f"record {args.env_id}")


def _record_single(rec: Any, policy: _Policy, args: argparse.Namespace, max_steps: int) -> None:
    with _progress(args) as bar:
        for k in range(args.episodes):
            obs, _ = rec.reset(seed=args.seed + k)
            for t in range(max_steps):
                raise_if_stopped()
                obs, _, terminated, truncated, _ = policy.step(rec, obs, f"episode {k}, step {t}")
                if _done(terminated, truncated).any():
                    break
            bar.update()


def _record_batched(rec: Any, policy: _Policy, args: argparse.Namespace, max_steps: int) -> None:
    """N parallel envs running episodes k = 0, 1, ... in the order they start, episode k with seed S+k. An env whose
    episode ends is reset alone (a partial reset: its episode is committed and the next one starts there) while it
    runs one of the `--episodes` wanted; an episode started past those (a reset must start one) gets seed S, is left
    running when it ends, and is dropped at the end: exactly the episodes wanted are recorded, with their seeds."""
    import numpy as np

    n, wanted = rec.meta.num_envs, args.episodes
    order = np.arange(n)  # the start order of each env's running episode
    obs, _ = rec.reset(seed=[args.seed + i for i in range(n)])
    started, steps = n, np.zeros(n, dtype=np.int64)
    with _progress(args) as bar:
        while len(rec.episodes_committed) < wanted:
            raise_if_stopped()
            obs, _, terminated, truncated, _ = policy.step(rec, obs, f"after {len(rec.episodes_committed)} episodes")
            steps += 1
            done = (_done(terminated, truncated) | (steps >= max_steps)) & (order < wanted)
            if done.any():
                idx = np.flatnonzero(done)
                before = len(rec.episodes_committed)
                new = np.arange(started, started + len(idx))
                seeds = [args.seed + int(k) if k < wanted else args.seed for k in new]
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
