"""`simreel recover`: rescue the committed episodes of an MCAP recording whose process was killed.

A recording process that dies (kill -9, crash, power cut) leaves an MCAP file without summary and
footer, which `inspect`/`replay`/`view` refuse. `recover` reads it front to back, writes every
committed episode into a complete file (in place unless `-o` is given) and reports what was lost: the
episodes still running at the time and any record cut in the middle. HDF5 recordings need no recovery
(their committed episodes stay readable); `recover` says so.
"""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "recover",
        help="rescue the committed episodes of an interrupted .mcap recording",
        description="Rewrite an MCAP recording whose process was killed into a complete file with every "
        "committed episode, and report what was lost.",
    )
    p.add_argument("path", metavar="PATH", help="the interrupted .mcap recording")
    p.add_argument("-o", "--output", metavar="OUT", default=None,
                   help="write the recovered recording here instead of replacing PATH (.mcap; .h5 writes HDF5)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from simreel.formats.copy import recover

    r = recover(args.path, args.output, overwrite=args.overwrite)
    if r.complete and r.output is None:
        print(f"{args.path} is complete ({r.episodes} episode(s), {r.steps} steps): nothing to recover")
        return 0
    print(f"recovered {r.episodes} committed episode(s), {r.steps} steps, into {r.output}")
    lost = list(r.unfinished)
    if r.lost_bytes:
        lost.append(f"{r.lost_bytes} byte(s) of a record cut short at the end of the file")
    if lost:
        print("lost (never committed): " + "; ".join(lost))
    else:
        print("lost: nothing (every episode that began was committed)")
    return 0
