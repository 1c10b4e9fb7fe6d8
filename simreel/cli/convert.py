"""`simreel convert`: copy a recording between HDF5 (.h5) and MCAP (.mcap), losslessly, episode by episode."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from simreel.cli.common import add_import_option, progress_bar

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "convert",
        help="convert a recording between .h5 and .mcap",
        description="Copy every episode of IN to OUT; the suffix of OUT picks the format (.h5 or .mcap). "
        "Arrays are copied bit-exactly both ways.",
    )
    p.add_argument("input", metavar="IN", help="recording to read (.h5 or .mcap)")
    p.add_argument("output", metavar="OUT", help="file to write: .h5/.hdf5 or .mcap")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--poses", action="store_true",
                   help="when IN has no body poses, compute every actor's and link's world pose by restoring each "
                   "recorded state into the rebuilt env (needs the task; OUT then holds them, so MCAP's /tf "
                   "shows every link)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_import_option(p)
    p.set_defaults(run=run)


def _link_poses(args: argparse.Namespace) -> Callable[[Any], Any]:
    """`--poses`: what adds every body's pose to each episode, in the env rebuilt with the task's code (the
    --import given now, else the recorded one, found here); None when IN has poses already."""

    def transform(meta: Any) -> Any:
        if meta.pose_bodies:
            return None
        from simreel.sim.poses import LinkPoses
        from simreel.sim.user_code import resolve_task_imports

        found = resolve_task_imports(meta.imports, explicit=args.imports, recording=args.input)
        poses = LinkPoses(dataclasses.replace(meta, imports=found))
        poses.meta.imports = list(meta.imports)  # OUT keeps what IN recorded, as a copy does
        return poses

    return transform


def run(args: argparse.Namespace) -> int:
    from simreel.formats import format_of
    from simreel.formats.copy import convert

    src = Path(args.input)
    report = convert(src, args.output, overwrite=args.overwrite, transform=_link_poses(args) if args.poses else None,
                     progress=lambda eps: progress_bar(eps, quiet=args.quiet, unit="ep", desc=f"convert {src.name}"))
    for note in report.skipped:
        sys.stderr.write(f"simreel convert: warning: {src}: {note} was never committed and is not copied\n")
    size = Path(args.output).stat().st_size
    print(f"converted {report.episodes} episode(s), {report.steps} steps, {args.input} → {args.output} "
          f"({size / 1024:.0f} KiB)")
    if format_of(args.output) == "mcap" and not report.meta.pose_bodies:
        print("note: IN has no body poses, so the MCAP transform channel (/tf) shows the actors and articulation "
              "roots of the state dict only; convert with --poses (or record with --poses) for every link")
    return 0
