"""`simreel filter`: keep (or split off) a recording's episodes by index, final success, length or a replay's
verdicts, losslessly, checked against the input after writing. Its criteria are `EpisodeCriteria`'s declarations,
how it writes `DatasetOptions`' (`simreel.datasets.options`); the files, the verdict reports and ``-q`` are
`FilterRun`'s."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simreel.cli.common import QUIET
from simreel.cli.merge import dataset_progress
from simreel.datasets.options import DatasetOptions, EpisodeCriteria
from simreel.errors import UsageError
from simreel.options.declare import add_arguments, from_arguments, option

__all__ = ["add_parser", "run", "FilterRun"]


@dataclass(frozen=True)
class FilterRun:
    """The options of `simreel filter` besides the criteria and how it writes: its files, each declared once."""

    output: str = option("", flags=("-o", "--output"), required=True, metavar="OUT",
                         help="file for the episodes kept (.h5 or .mcap)")
    rest: str | None = option(None, metavar="OTHER", help="file for every episode not kept (.h5 or .mcap)")
    verified: str | None = option(None, metavar="REPORT", group="verdict",
                                  help="episodes a replay report (simreel replay --report) says verified: exact or "
                                       "within tolerance; episodes it does not cover are not kept")
    diverged: str | None = option(None, metavar="REPORT", group="verdict",
                                  help="episodes a replay report says diverged")
    quiet: bool = option(False, spec=QUIET)


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "filter",
        help="keep or split off a recording's episodes by index, success, length or replay verdict",
        description="Copy the episodes of IN that meet every criterion given into OUT (numbered 0..N-1; each keeps "
        "its origin), and with --rest the others into OTHER: a split. OUT's suffix picks the format. The outputs "
        "are read back and every array checked against IN.",
    )
    p.add_argument("input", metavar="IN", help="recording to read (.h5, .mcap, ManiSkill .h5 + .json)")
    add_arguments(p, FilterRun, only=["output", "rest"])
    add_arguments(p, EpisodeCriteria)
    add_arguments(p, FilterRun, only=["verified", "diverged"])
    add_arguments(p, DatasetOptions)
    add_arguments(p, FilterRun, only=["quiet"])
    p.set_defaults(run=run)


def _criteria(args: argparse.Namespace, cmd: FilterRun) -> EpisodeCriteria:
    criteria = from_arguments(EpisodeCriteria, args, **_verdicts(args.input, cmd))
    if criteria.episodes is not None and not criteria.episodes:
        raise UsageError(f"--episodes {args.episodes!r} names no episode")
    return criteria


def _verdicts(path: str, cmd: FilterRun) -> dict[str, Any]:
    """The verdict criterion of --verified/--diverged REPORT: the report's verdicts of IN's episodes."""
    report = cmd.verified or cmd.diverged
    if report is None:
        return {}
    from simreel.datasets.dataset import DIVERGED, VERIFIED, report_verdicts
    from simreel.replay import read_verdicts

    found = read_verdicts(report)
    return {"verdicts": report_verdicts(path, found.verdicts, found.files, report),
            "keep_verdicts": VERIFIED if cmd.verified else DIVERGED, "report": str(Path(report).resolve())}


def run(args: argparse.Namespace) -> int:
    from simreel.datasets.dataset import filter_recording

    cmd = from_arguments(FilterRun, args)
    options = from_arguments(DatasetOptions, args, command=args.command_line, progress=dataset_progress(cmd.quiet))
    report = filter_recording(args.input, cmd.output, _criteria(args, cmd), options, rest=cmd.rest)
    print(report.summary())
    return 0
