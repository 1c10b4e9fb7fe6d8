"""`simreel audit`: check that a task's state dict holds all of its state; exit 0 clean, 1 with findings."""

from __future__ import annotations

import argparse
from typing import Any

from simreel.cli.common import GivenOnce, parse_index_ranges, write_json_report
from simreel.errors import UsageError
from simreel.io.durable import raise_if_stopped
from simreel.options.declare import add_arguments, from_arguments
from simreel.replay.audit.options import AuditOptions

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "audit",
        help="audit a task for state that its state dict does not capture",
        description=(
            "Run ENV_ID for some steps, restore its state dict into a second instance reset with another seed, "
            "and compare everything the task computes (state dict, evaluate() info, observations, reward), "
            "then step both and compare again; also check get/set round-trips, controller state and that the "
            "state-dict layout does not depend on the seed. With --policy or --trajectory, do the same at every "
            "step of real trajectories (after grasps, at success, with joints moving), naming the step and phase "
            "of each finding. Exit status: 0 clean, 1 findings, 2 bad input."
        ),
    )
    p.add_argument("env_id", metavar="ENV_ID", nargs="?", default=None,
                   help="the task (may be left out with --trajectory: the recording names it)")
    add_arguments(p, AuditOptions, only=["steps"])
    along = p.add_mutually_exclusive_group()
    along.add_argument("--policy", default=None, metavar="POLICY",
                       help="also audit along episodes of this policy: scripted (the task's shipped one), "
                            "MODULE:CALLABLE or FILE.py:CALLABLE")
    add_arguments(along, AuditOptions, only=["trajectory"])
    p.add_argument("--episodes", action=GivenOnce, default=None, metavar="N|LIST",
                   help="with --policy: how many episodes (seeds S, S+1, ...; default 1); with --trajectory: which "
                        "episodes, e.g. 0,3-5 (default all)")
    add_arguments(p, AuditOptions, only=["every", "seed"])
    p.add_argument("--json", default=None, metavar="PATH", help="write the findings as JSON here")
    p.add_argument("--overwrite", action="store_true", help="replace the --json file if it exists")
    add_arguments(p, AuditOptions, only=["control_mode", "obs_mode", "reward_mode", "env_kwargs"])
    p.add_argument("-q", "--quiet", action="store_true", help="print only the findings")
    add_arguments(p, AuditOptions, only=["imports", "trust_recorded_imports"])
    p.set_defaults(run=run)


def _along(args: argparse.Namespace) -> dict[str, Any]:
    """The AuditOptions fields of --policy / --trajectory / --episodes / --every."""
    if args.episodes is not None and args.policy is None and args.trajectory is None:
        raise UsageError("--episodes needs --policy or --trajectory")
    out: dict[str, Any] = {}
    if args.trajectory is not None and args.episodes is not None:
        out["trajectory_episodes"] = parse_index_ranges(args.episodes)
    if args.policy is not None:
        if args.env_id is None:
            raise UsageError("--policy needs the task's ENV_ID")
        from simreel.cli.policy_option import PolicyCall, load_policy
        from simreel.sim.user_code import import_user_code

        for spec in args.imports:  # a user policy may live in an --import module
            import_user_code(spec)
        call = PolicyCall(args.policy, load_policy(args.policy, args.env_id), check=True)
        out.update(policy=lambda env, obs: call(env, obs), policy_name=f"--policy {args.policy}")
        if args.episodes is not None:
            if not (args.episodes.isascii() and args.episodes.isdigit()):
                raise UsageError(f"--episodes with --policy is a number of episodes, got {args.episodes!r}")
            out["episodes"] = int(args.episodes)
    return out


def _check_json(args: argparse.Namespace) -> None:
    """Refuse --json, before any env is built, where the report would replace the recording audited (--trajectory)
    or a file of it, or a file another recording keeps beside it (its JSON sidecar), `--overwrite` or not; without
    --overwrite, any file. Nothing of the recording is ever replaced by a report of it."""
    from simreel.formats import check_report_writable, recording_files
    from simreel.io.targets import check_distinct

    if args.trajectory is not None:
        check_distinct({"--json": [args.json]}, recording_files(args.trajectory),
                       input_label="the --trajectory recording")
    check_report_writable(args.json, overwrite=args.overwrite, option="--json")


def run(args: argparse.Namespace) -> int:
    if args.steps < 1:
        raise UsageError(f"--steps must be >= 1, got {args.steps}")
    if args.env_id is None and args.trajectory is None:
        raise UsageError("name the task to audit (ENV_ID), or a recording with --trajectory")
    from simreel.replay.audit.audit import audit_task

    if args.json is not None:
        _check_json(args)
    options = from_arguments(AuditOptions, args, **_along(args))
    report = audit_task(args.env_id, options)
    raise_if_stopped()  # a Ctrl-C a library swallowed on the way: no report of a run asked to stop
    text = report.summary()
    if args.quiet:
        text = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith(("checked:", "note:")))
    print(text)
    if args.json:
        write_json_report(args.json, report.to_json(), kept="its findings are the lines above",
                          again="audit again")
    return 0 if report.ok else 1
