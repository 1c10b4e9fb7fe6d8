"""`simreel export IN... --to lerobot OUT`: recordings (files, folders, patterns) as a LeRobot dataset v3.0 folder
(`simreel.training.lerobot.export`), the verified episodes only when a replay report is given."""

from __future__ import annotations

import argparse
from typing import Any

from simreel.cli.common import QUIET, progress_bar
from simreel.cli.export_rendered import RENDER_OPTIONS, export_rendered, render_options
from simreel.errors import UsageError
from simreel.options.declare import add_arguments, add_option, from_arguments
from simreel.replay.convert.options import ConvertOptions
from simreel.training.lerobot.options import FORMATS, ExportOptions

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "export",
        help="export recordings to a training format: a LeRobot dataset v3.0",
        description="Write the episodes of the recordings IN (files, folders, glob patterns) as a LeRobot dataset "
        "v3.0 in the folder OUT: parquet data files of many episodes each, at the env's control frequency, with "
        "observation.state, action, next.reward, next.success, next.done and the index columns, each recorded camera "
        "as an H.264 video (observation.images.<camera>), meta/info.json "
        "(the source files and the report's verdicts under \"simreel\"), stats.json, tasks and the episodes table. "
        "With --report, only the episodes the replay verified. With --obs-mode (e.g. rgb), the observations are "
        "re-rendered from the recorded states first, as `simreel convert --obs-mode` does (each restored state "
        "checked; episodes that fail the check are left out, named, and the exit status is 1), for a recording "
        "made without them (the default) or its cameras at another --camera-size.",
    )
    p.add_argument("inputs", nargs="+", metavar="IN", help="recordings: .h5/.mcap files, folders or glob patterns")
    p.add_argument("--to", required=True, nargs=2, metavar=("FORMAT", "OUT"),
                   help=f"the format ({', '.join(FORMATS)}) and the folder to write (a new one, or a dataset of that "
                        "format with --overwrite)")
    add_arguments(p, ExportOptions)
    add_option(p, "quiet", QUIET, False)
    add_arguments(p, ConvertOptions, only=RENDER_OPTIONS)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from simreel.training.lerobot.export import export_lerobot

    fmt, output = args.to
    if fmt not in FORMATS:
        raise UsageError(f"--to {fmt}: simreel exports to {', '.join(FORMATS)}")
    options = from_arguments(ExportOptions, args, command=args.command_line)
    render = render_options(args)
    if render is not None:
        return export_rendered(args.inputs, output, options, render, quiet=args.quiet)
    with progress_bar(quiet=args.quiet, unit="frame", desc="export") as bar:
        summary = export_lerobot(args.inputs, output, options, progress=bar.update)
    print(summary.summary())
    return 0
