"""`simreel replay`: replay a recording and verify every step; exit 0 when every episode verifies, 1 if any diverges."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from simreel.cli.common import add_import_option, add_tolerance_options, parse_index_ranges, progress_bar
from simreel.errors import UsageError

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="replay a recording and verify it step by step",
        description=(
            "Rebuild the recorded env, replay each episode and compare every state-dict leaf, reward, flag, "
            "info entry and contact force with the recording. Exit status: 0 every episode verifies "
            "(exact or within tolerance), 1 some episode diverged, 2 bad input."
        ),
    )
    p.add_argument("path", metavar="PATH", help="a simreel recording (.h5 or .mcap)")
    add_tolerance_options(
        p,
        mode_help="actions: step the recorded actions from the reproduced reset (default); "
                  "states: restore every recorded state and recompute reward/info/obs; "
                  "step: restore state t, step action t, compare with state t+1 (one-step error)",
    )
    p.add_argument("--resync", type=int, default=None, metavar="K",
                   help="with --mode actions: restore the recorded state every K steps")
    p.add_argument("--episodes", default=None, metavar="LIST", help="episodes to replay, e.g. 0,3-7 (default: all)")
    p.add_argument("--report", default=None, metavar="REPORT.json", help="write the JSON report here")
    p.add_argument("-o", "--output", default=None, metavar="REPLAYED", help="write the replayed episodes (.h5/.mcap)")
    p.add_argument("--overwrite", action="store_true", help="replace the -o and --report files if they exist")
    p.add_argument("--obs-mode", default=None,
                   help="observation mode of the replay (e.g. rgb with --mode states -o OUT to re-render)")
    p.add_argument("--sim-backend", default=None,
                   help="replay on another sim backend than the recorded one (physx_cpu, physx_cuda); a GPU "
                        "recording on a machine without CUDA: physx_cpu (another engine, so the verdict is not exact)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="parallel processes (default 1)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_import_option(p)
    p.set_defaults(run=run)


def _options(args: argparse.Namespace) -> Any:
    from simreel.replay.verify import ReplayOptions

    episodes = None if args.episodes is None else parse_index_ranges(args.episodes)
    if episodes is not None and not episodes:
        raise UsageError(f"--episodes {args.episodes!r} names no episode")
    return ReplayOptions(mode=args.mode, resync=args.resync, episodes=episodes, atol=args.atol,
                         group_tolerances=dict(args.tol), output=args.output, overwrite=args.overwrite,
                         obs_mode=args.obs_mode, workers=args.workers, imports=args.imports,
                         sim_backend=args.sim_backend, command=args.command_line)


def run(args: argparse.Namespace) -> int:
    from simreel.formats import recording_files
    from simreel.formats.targets import check_distinct, check_output, write_text_atomic
    from simreel.replay.verify import ReplayRun

    if args.report is not None:
        outputs = {"-o": recording_files(args.output) if args.output else [], "--report": [args.report]}
        check_distinct(outputs, recording_files(args.path), input_label="the recording being replayed")
        check_output(args.report, overwrite=args.overwrite, option="--report")
    with ReplayRun(args.path, _options(args)) as replay:  # a bad file or option fails here, before any env
        bar = progress_bar(quiet=args.quiet, total=replay.total, unit="ep", desc=f"replay {replay.reader.meta.env_id}")

        def progress(ep: Any) -> None:
            bar.set_postfix_str(f"{ep.index}: {ep.verdict}")
            bar.update()

        with bar:
            report = replay.execute(progress)
    for line in report.warnings:
        sys.stderr.write(f"simreel replay: warning: {line}\n")
    print(report.summary())
    if args.output:
        print(f"replayed episodes written to {args.output}")
    if args.report:
        write_text_atomic(args.report, json.dumps(report.to_json(), indent=2) + "\n")
    return 0 if report.ok else 1
