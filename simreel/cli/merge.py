"""`simreel merge`: several recordings of one env (simreel HDF5/MCAP, ManiSkill's files, mixed) into one file,
losslessly, checked against the inputs after writing."""

from __future__ import annotations

import argparse
from typing import Any

from simreel.cli.common import progress_bar

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "merge",
        help="merge recordings of one env into one file",
        description="Copy every episode of each IN, in order, into OUT (numbered 0..N-1; each keeps its origin). "
        "The inputs must record the same env (settings, layouts, simulator versions). OUT's suffix picks the "
        "format (.h5 or .mcap). OUT is read back and every array checked against its source.",
    )
    p.add_argument("inputs", nargs="+", metavar="IN", help="recordings to merge (.h5, .mcap, ManiSkill .h5 + .json)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="file to write: .h5/.hdf5 or .mcap")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def dataset_progress(quiet: bool) -> Any:
    """The progress bars of `merge` and `filter`: one per pass (copy, then the check of each output)."""
    return lambda items, what: progress_bar(items, quiet=quiet, unit="ep", desc=what)


def run(args: argparse.Namespace) -> int:
    from simreel.datasets.dataset import merge

    report = merge(args.inputs, args.output, overwrite=args.overwrite, command=args.command_line,
                   progress=dataset_progress(args.quiet))
    print(report.summary())
    return 0
