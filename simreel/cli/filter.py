"""`simreel filter`: keep (or split off) a recording's episodes by index, final success, length or a replay's
verdicts, losslessly, checked against the input after writing."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from simreel.cli.common import GivenOnce, parse_index_ranges
from simreel.cli.merge import dataset_progress
from simreel.errors import UsageError

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "filter",
        help="keep or split off a recording's episodes by index, success, length or replay verdict",
        description="Copy the episodes of IN that meet every criterion given into OUT (numbered 0..N-1; each keeps "
        "its origin), and with --rest the others into OTHER: a split. OUT's suffix picks the format. The outputs "
        "are read back and every array checked against IN.",
    )
    p.add_argument("input", metavar="IN", help="recording to read (.h5, .mcap, ManiSkill .h5 + .json)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="file for the episodes kept (.h5 or .mcap)")
    p.add_argument("--rest", default=None, metavar="OTHER", help="file for every episode not kept (.h5 or .mcap)")
    p.add_argument("--episodes", action=GivenOnce, default=None, metavar="LIST", help="original episode indices, e.g. 0,3-7")
    success = p.add_mutually_exclusive_group()
    success.add_argument("--success", dest="success", action="store_const", const=True, default=None,
                         help="episodes whose final success is true (a file without success has none)")
    success.add_argument("--no-success", dest="success", action="store_const", const=False,
                         help="episodes whose final success is false")
    p.add_argument("--min-steps", type=int, default=None, metavar="N", help="episodes of at least N steps")
    p.add_argument("--max-steps", type=int, default=None, metavar="N", help="episodes of at most N steps")
    verdict = p.add_mutually_exclusive_group()
    verdict.add_argument("--verified", default=None, metavar="REPORT",
                         help="episodes a replay report (simreel replay --report) says verified: exact or within "
                              "tolerance; episodes it does not cover are not kept")
    verdict.add_argument("--diverged", default=None, metavar="REPORT",
                         help="episodes a replay report says diverged")
    p.add_argument("--overwrite", action="store_true", help="replace OUT and OTHER if they exist")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def _criteria(args: argparse.Namespace) -> Any:
    from simreel.datasets.dataset import EpisodeCriteria

    episodes = None if args.episodes is None else parse_index_ranges(args.episodes)
    if episodes is not None and not episodes:
        raise UsageError(f"--episodes {args.episodes!r} names no episode")
    return EpisodeCriteria(episodes=episodes, success=args.success,
                           min_steps=args.min_steps, max_steps=args.max_steps, **_verdicts(args))


def _verdicts(args: argparse.Namespace) -> dict[str, Any]:
    """The verdict criterion of --verified/--diverged REPORT: the report's verdicts of IN's episodes."""
    report = args.verified or args.diverged
    if report is None:
        return {}
    from simreel.datasets.dataset import DIVERGED, VERIFIED, report_verdicts
    from simreel.replay import read_verdicts

    found = read_verdicts(report)
    return {"verdicts": report_verdicts(args.input, found.verdicts, found.files, report),
            "keep_verdicts": VERIFIED if args.verified else DIVERGED, "report": str(Path(report).resolve())}


def run(args: argparse.Namespace) -> int:
    from simreel.datasets.dataset import filter_recording

    report = filter_recording(args.input, args.output, _criteria(args), rest=args.rest, overwrite=args.overwrite,
                              command=args.command_line, progress=dataset_progress(args.quiet))
    print(report.summary())
    return 0
