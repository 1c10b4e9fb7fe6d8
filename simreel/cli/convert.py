"""`simreel convert`: copy a recording between HDF5 (.h5) and MCAP (.mcap), losslessly; or, with --obs-mode and/or
--control-mode, convert it (re-render observations from the recorded states, convert actions to another control
mode) and verify every episode step by step (`simreel.replay.convert.convert`). Only verified episodes are
written unless --keep all. Exit 0 when every converted episode verifies, 1 when one does not (written or left out)
or nothing was written, 2 on bad input."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from simreel.cli.common import QUIET, progress_bar, write_json_report
from simreel.errors import UsageError
from simreel.options.declare import (
    add_arguments,
    add_option,
    changed_on_command_line,
    cli_names,
    from_arguments,
)
from simreel.replay.convert.options import ConvertOptions

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "convert",
        help="convert a recording between .h5 and .mcap, or to another obs/control mode (verified)",
        description="Copy every episode of IN to OUT; the suffix of OUT picks the format (.h5 or .mcap). Arrays are "
        "copied as they are, bit for bit, both ways (the copy is not read back: `simreel merge IN -o OUT` copies and "
        "checks every array). With --obs-mode and/or --control-mode, convert instead: observations are "
        "re-rendered from the recorded states, actions converted to the control mode and replayed from each reset, "
        "and every episode is checked step by step against IN: only verified ones are written unless --keep all "
        "(exit 1 when one is not verified).",
    )
    p.add_argument("input", metavar="IN", help="recording to read (.h5 or .mcap; simreel's or ManiSkill's)")
    p.add_argument("output", metavar="OUT", help="file to write: .h5/.hdf5 or .mcap")
    add_arguments(p, ConvertOptions, only=["overwrite"])
    p.add_argument("--poses", action="store_true",
                   help="when IN has no body poses, compute every actor's and link's world pose by restoring each "
                   "recorded state into the rebuilt env (needs the task; OUT then holds them, so MCAP's /tf "
                   "shows every link)")
    g = p.add_argument_group("conversion (verified)")
    add_arguments(g, ConvertOptions, only=[n for n in cli_names(ConvertOptions) if n not in _EVERY_CONVERT])
    g.add_argument("--report", default=None, metavar="REPORT.json", help="write the JSON report here (per-step errors)")
    add_option(p, "quiet", QUIET, False)
    add_arguments(p, ConvertOptions, only=["imports", "trust_recorded_imports"])
    p.set_defaults(run=run)


_EVERY_CONVERT = ("overwrite", "imports", "trust_recorded_imports")
"""The `ConvertOptions` a lossless copy takes too (the rest are the conversion's group)."""
_COPY_IGNORES = ("workers",)
"""A conversion option a copy takes without a word (it runs in one process)."""


def _converting(args: argparse.Namespace) -> bool:
    """Whether this is a verified conversion (else a lossless copy, which takes none of its options)."""
    if args.obs_mode is not None or args.control_mode is not None:
        return True
    conversion = [n for n in cli_names(ConvertOptions) if n not in (*_EVERY_CONVERT, *_COPY_IGNORES)]
    given = changed_on_command_line(ConvertOptions, args, conversion)  # given, even as "" or 0
    given += ["--report"] if args.report is not None else []
    if given:
        raise UsageError(f"{', '.join(given)} apply to a conversion: add --obs-mode and/or --control-mode "
                         "(without them, convert copies IN to another format as it is)")
    return False


def run(args: argparse.Namespace) -> int:
    if _converting(args):
        return _convert(args)
    return _copy(args)


# --------------------------------------------------------------------------------------- a lossless copy
def _link_poses(args: argparse.Namespace) -> Callable[[Any], Any]:
    """`--poses`: what adds every body's pose to each episode, in the env rebuilt with the task's code (the
    --import given now, else the recorded one, found here); None when IN has poses already."""

    def transform(meta: Any) -> Any:
        if meta.pose_bodies:
            return None
        if not meta.state_layout:
            raise UsageError(f"--poses: {args.input} holds no env states, from which the poses are computed; "
                             "convert it without --poses (or replay it with `simreel replay -o` first, which "
                             "records the states it reaches)")
        from simreel.datasets.poses import LinkPoses
        from simreel.sim.user_code import resolve_task_imports

        found = resolve_task_imports(meta.imports, explicit=args.imports, recording=args.input,
                                     trust=args.trust_recorded_imports)
        poses = LinkPoses(dataclasses.replace(meta, imports=found))
        poses.meta.imports = list(meta.imports)  # OUT keeps what IN recorded, as a copy does
        return poses

    return transform


def _copy(args: argparse.Namespace) -> int:
    from simreel.datasets.copy import convert
    from simreel.formats import format_of

    src = Path(args.input)
    report = convert(src, args.output, overwrite=args.overwrite, transform=_link_poses(args) if args.poses else None,
                     progress=lambda eps: progress_bar(eps, quiet=args.quiet, unit="ep", desc=f"convert {src.name}"))
    for note in report.skipped:
        sys.stderr.write(f"simreel convert: warning: {src}: {note} was never committed and is not copied\n")
    for note in report.notes:
        sys.stderr.write(f"simreel convert: warning: {src}: {note}\n")
    size = Path(args.output).stat().st_size
    print(f"converted {report.episodes} episode(s), {report.steps} steps, {args.input} → {args.output} "
          f"({size / 1024:.0f} KiB)")
    if format_of(args.output) == "mcap" and not report.meta.pose_bodies:
        print("note: IN has no body poses, so the MCAP transform channel (/tf) shows the actors and articulation "
              "roots of the state dict only; convert with --poses (or record with --poses) for every link")
    if format_of(args.output) == "mcap":
        print("note: a copy holds no shapes for Foxglove and Rerun (/scene, /robot_description): only a recording "
              "made to .mcap draws its scene; `simreel view` draws any recording")
    return 0


# --------------------------------------------------------------------------------------- a verified conversion
def _options(args: argparse.Namespace) -> Any:
    if args.poses:
        raise UsageError("--poses applies to a copy between formats, not to a conversion")
    options = from_arguments(ConvertOptions, args, command=args.command_line)
    if options.episodes is not None and not options.episodes:
        raise UsageError(f"--episodes {args.episodes!r} names no episode")
    if options.group_tolerances and args.control_mode is None:
        raise UsageError("--tol sets the tracking tolerances of a control-mode conversion: add --control-mode")
    return options


def _convert(args: argparse.Namespace) -> int:
    from simreel.formats import check_report_writable, recording_files
    from simreel.io.targets import check_distinct
    from simreel.replay.convert.run import ConversionRun

    options = _options(args)
    if args.report is not None:
        check_distinct({"OUT": recording_files(args.output), "--report": [args.report]}, recording_files(args.input),
                       input_label="IN")
        check_report_writable(args.report, overwrite=args.overwrite, option="--report")
    with ConversionRun(args.input, args.output, options) as conversion:  # bad files and options fail here
        bar = progress_bar(quiet=args.quiet, total=conversion.total, unit="ep",
                           desc=f"convert {conversion.reader.meta.env_id}")

        def progress(ep: Any) -> None:
            bar.set_postfix_str(f"{ep.index}: {ep.verdict}", refresh=False)
            bar.update()

        with bar:
            report = conversion.execute(progress)
    for line in report.warnings:
        sys.stderr.write(f"simreel convert: warning: {line}\n")
    print(report.summary())
    if args.report:
        write_json_report(args.report, report.to_json(), kept=f"{args.output} was written and kept",
                          again="convert again with --overwrite for the report")
    return 0 if report.ok else 1
