"""`simreel merge`: several recordings of one env (simreel HDF5/MCAP, ManiSkill's files, mixed) into one file,
losslessly, checked against the inputs after writing."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

from simreel.cli.common import QUIET, progress_bar
from simreel.datasets.options import DatasetOptions
from simreel.options.declare import add_arguments, from_arguments, option

__all__ = ["add_parser", "run", "MergeRun"]


@dataclass(frozen=True)
class MergeRun:
    """The options of `simreel merge` besides how it writes (`DatasetOptions`), each declared once."""

    output: str = option("", flags=("-o", "--output"), required=True, metavar="OUT",
                         help="file to write: .h5/.hdf5 or .mcap")
    quiet: bool = option(False, spec=QUIET)


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "merge",
        help="merge recordings of one env into one file",
        description="Copy every episode of each IN, in order, into OUT (numbered 0..N-1; each keeps its origin). "
        "The inputs must record the same env (settings, layouts, simulator versions). OUT's suffix picks the "
        "format (.h5 or .mcap). OUT is read back and every array checked against its source.",
    )
    p.add_argument("inputs", nargs="+", metavar="IN", help="recordings to merge (.h5, .mcap, ManiSkill .h5 + .json)")
    add_arguments(p, MergeRun, only=["output"])
    add_arguments(p, DatasetOptions)
    add_arguments(p, MergeRun, only=["quiet"])
    p.set_defaults(run=run)


def dataset_progress(quiet: bool) -> Any:
    """The progress bars of `merge` and `filter`: one per pass (copy, then the check of each output)."""
    return lambda items, what: progress_bar(items, quiet=quiet, unit="ep", desc=what)


def run(args: argparse.Namespace) -> int:
    from simreel.datasets.dataset import merge

    cmd = from_arguments(MergeRun, args)
    options = from_arguments(DatasetOptions, args, command=args.command_line, progress=dataset_progress(cmd.quiet))
    report = merge(args.inputs, cmd.output, options)
    print(report.summary())
    return 0
