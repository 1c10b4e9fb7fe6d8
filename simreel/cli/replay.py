"""`simreel replay`: replay recordings and verify every step; exit 0 when every episode verifies, 1 if any diverges,
2 when a recording or an episode could not be replayed (bad input). Its options are `ReplayOptions`' declarations
(`simreel.replay.run.options`); only the recordings, ``--resume`` and ``-q`` are the command's own."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from simreel.cli.common import QUIET, progress_bar, stopped_saying
from simreel.errors import UsageError
from simreel.options.declare import (
    add_arguments,
    add_option,
    changed_on_command_line,
    cli_names,
    from_arguments,
    names_tagged,
)
from simreel.replay.run.options import ReplayOptions

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="replay recordings and verify them step by step",
        description=(
            "Rebuild the recorded env, replay each episode and compare every state-dict leaf, reward, flag, "
            "info entry and contact force with the recording. PATH: recordings (.h5, .mcap, ManiSkill .h5), "
            "folders of them, or glob patterns; their episodes are one work list. Exit status: 0 every episode "
            "verifies (exact or within tolerance), 1 some episode diverged, 2 bad input (a recording or an "
            "episode that cannot be replayed included)."
        ),
    )
    p.add_argument("paths", nargs="*", metavar="PATH", help="recordings, folders of recordings, or glob patterns")
    add_arguments(p, ReplayOptions)
    p.add_argument("--resume", default=None, metavar="REPORT.json",
                   help="finish the run that wrote REPORT.json (interrupted, killed): replay only the episodes it "
                        "has no verdict for, with its recordings and options (not a run with -o)")
    add_option(p, "quiet", QUIET, False)
    p.set_defaults(run=run)


def _build_run(args: argparse.Namespace) -> Any:
    from simreel.replay.run.verify import ReplayRun

    if args.resume is not None:
        execution = names_tagged(ReplayOptions, "execution")
        changed = changed_on_command_line(ReplayOptions, args,
                                          [n for n in cli_names(ReplayOptions) if n not in execution])
        if args.paths or changed:
            what = "PATH" if args.paths else changed[0]
            raise UsageError(f"--resume takes the recordings and options from the report; drop {what} (only "
                             "--workers, --ray, --ship, --trust-recorded-imports and -q may change)")
        return ReplayRun.resume(args.resume, workers=args.workers, ray=args.ray, ship=args.ship,
                                trust_recorded_imports=args.trust_recorded_imports, command=args.command_line)
    if not args.paths:
        raise UsageError("name the recordings to replay (files, folders, patterns), or --resume REPORT.json")
    options = from_arguments(ReplayOptions, args, command=args.command_line)
    if options.episodes is not None and not options.episodes:
        raise UsageError(f"--episodes {args.episodes!r} names no episode")
    return ReplayRun(args.paths, options)


def run(args: argparse.Namespace) -> int:
    from simreel.datasets.inputs import shown_path

    replay = _build_run(args)  # a bad file, report or option fails here, before any env
    files = replay.worklist.readable
    desc = f"replay {files[0].meta.env_id}" if len(files) == 1 else f"replay {len(files)} recordings"
    bar = progress_bar(quiet=args.quiet, total=replay.total + replay.worklist.skipped,
                       initial=replay.worklist.skipped, unit="ep", desc=desc)

    def progress(item: Any, report: Any) -> None:
        where = f"{shown_path(item.path)}:{item.index}" if len(files) > 1 else str(item.index)
        bar.set_postfix_str(f"{where} {report.verdict}", refresh=False)
        bar.update()

    try:
        with bar:
            tally = replay.execute(progress)
    except KeyboardInterrupt as stop:
        if replay.report_json is not None or replay.options.output is not None:
            stopped_saying(stop, replay.how_to_finish())
        raise
    _print(tally, replay)
    return tally.exit_status()


def _print(tally: Any, replay: Any) -> None:
    from simreel.datasets.inputs import shown_path

    for f in tally.files.values():
        where = f"{shown_path(f.path)}: " if len(tally.files) > 1 else ""
        for line in f.warnings:
            sys.stderr.write(f"simreel replay: warning: {where}{line}\n")
    print(tally.summary())
    if replay.worklist.skipped:
        print(f"resumed {replay.report_json}: {replay.worklist.skipped} episode(s) already had their verdict")
    out = replay.options.output
    if out and Path(out).exists():
        print(f"replayed episodes written to {out}")
    elif out:
        print(f"nothing written to {out}: no episode could be replayed")
    if replay.report_json is not None:
        print(f"report: {replay.report_json} (each verdict as it came: {replay.report_log})")
