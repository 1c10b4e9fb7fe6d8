"""`simreel recover`: rescue the intact committed episodes of a recording whose process was killed or whose file
is damaged.

A recording process that dies (kill -9, crash, power cut) leaves an MCAP file without summary and
footer, which `inspect`/`replay`/`view` refuse, and an HDF5 file whose committed episodes stay readable
but whose JSON sidecar may lag and whose side folder names the episodes that were running. `recover`
reads what it can (an MCAP file front to back, skipping a damaged record and going on from the next
whole one), writes every intact committed episode into a complete file (in place, replacing the old one
only once the new one is complete, unless `-o` is given) and names what was lost: episodes still running
at the time, damaged episodes, records and bytes.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

from simreel.options.declare import add_arguments, from_arguments, option

__all__ = ["add_parser", "run", "RecoverRun"]


@dataclass(frozen=True)
class RecoverRun:
    """The options of `simreel recover`, each declared once: the keywords of `simreel.datasets.copy.recover`, which
    checks them (for a Python caller too)."""

    output: str | None = option(None, flags=("-o", "--output"), metavar="OUT",
                                help="write the recovered recording here instead of replacing PATH (.mcap; .h5 "
                                     "writes HDF5)")
    overwrite: bool = option(False, action="store_true", help="replace OUT if it exists")


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "recover",
        help="rescue the committed episodes of an interrupted or damaged recording",
        description="Rewrite a recording whose process was killed, or whose file is damaged, into a complete file "
        "with every intact committed episode, and report what was lost. MCAP: a file cut short or with damaged "
        "records; HDF5: a killed recording's running episodes, damaged chunks or episodes (an HDF5 file cut short, "
        "shorter than it says it is, cannot be opened at all).",
    )
    p.add_argument("path", metavar="PATH", help="the interrupted or damaged recording (.mcap or .h5)")
    add_arguments(p, RecoverRun)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from simreel.datasets.copy import recover

    cmd = from_arguments(RecoverRun, args)
    r = recover(args.path, cmd.output, overwrite=cmd.overwrite)
    if r.finished:
        print(r.finished)
    if r.complete and r.output is None:
        print(f"{args.path} is complete ({r.episodes} episode(s), {r.steps} steps): nothing to recover")
        return 0
    print(f"recovered {r.episodes} committed episode(s), {r.steps} steps, into {r.output}")
    lost = list(r.unfinished)
    if r.lost_bytes:
        lost.append(f"{r.lost_bytes} byte(s) of a record cut short at the end of the file")
    if lost:
        print("lost (never committed): " + "; ".join(lost))
    if r.damaged:
        print("lost (damaged): " + "; ".join(r.damaged))
    if not lost and not r.damaged:
        print("lost: nothing so far (the recording still runs: its running episodes are not in the copy)" if r.live
              else "lost: nothing (every episode that began was committed)")
    for note in r.notes:
        print(f"found: {note}")
    return 0
