"""`simreel audit`: check that a task's state dict holds all of its state; exit 0 clean, 1 with findings."""

from __future__ import annotations

import argparse
import json
from typing import Any

from simreel.cli.common import add_import_option, parse_json_kwargs
from simreel.errors import UsageError

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "audit",
        help="audit a task for state that its state dict does not capture",
        description=(
            "Run ENV_ID for some steps, restore its state dict into a second instance reset with another seed, "
            "and compare everything the task computes (state dict, evaluate() info, observations, reward), "
            "then step both and compare again; also check get/set round-trips, controller state and that the "
            "state-dict layout does not depend on the seed. Exit status: 0 clean, 1 findings, 2 bad input."
        ),
    )
    p.add_argument("env_id", metavar="ENV_ID")
    p.add_argument("--steps", type=int, default=20, metavar="N", help="random steps before the restore (default 20)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the first instance; the second uses S+1")
    p.add_argument("--json", default=None, metavar="PATH", help="write the findings as JSON here")
    p.add_argument("--overwrite", action="store_true", help="replace the --json file if it exists")
    p.add_argument("--control-mode", default=None, help="ManiSkill control_mode (default: the task's)")
    p.add_argument("--obs-mode", default="state", help="observation mode whose observations are compared (default state)")
    p.add_argument("--reward-mode", default=None, help="ManiSkill reward_mode (default: the task's)")
    p.add_argument("--env-kwargs", type=parse_json_kwargs, default={}, metavar="JSON",
                   help='extra gym.make kwargs as a JSON object')
    p.add_argument("-q", "--quiet", action="store_true", help="print only the findings")
    add_import_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.steps < 1:
        raise UsageError(f"--steps must be >= 1, got {args.steps}")
    from simreel.formats.targets import check_output, write_text_atomic
    from simreel.replay.audit import AuditOptions, audit_task

    if args.json is not None:
        check_output(args.json, overwrite=args.overwrite, option="--json")
    options = AuditOptions(imports=tuple(args.imports), steps=args.steps, seed=args.seed, control_mode=args.control_mode,
                           obs_mode=args.obs_mode, reward_mode=args.reward_mode, env_kwargs=args.env_kwargs)
    report = audit_task(args.env_id, options)
    text = report.summary()
    if args.quiet:
        text = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith(("checked:", "note:")))
    print(text)
    if args.json:
        write_text_atomic(args.json, json.dumps(report.to_json(), indent=2) + "\n")
    return 0 if report.ok else 1
