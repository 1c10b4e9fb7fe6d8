"""`simreel replay`: replay recordings and verify every step; exit 0 when every episode verifies, 1 if any diverges,
2 when a recording or an episode could not be replayed (bad input)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from simreel.cli.common import (
    GivenOnce,
    add_import_option,
    add_tolerance_options,
    parse_index_ranges,
    progress_bar,
)
from simreel.errors import UsageError

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
    add_tolerance_options(
        p,
        mode_help="actions: step the recorded actions from the reproduced reset (default); "
                  "states: restore every recorded state and recompute reward/info/obs; "
                  "step: restore state t, step action t, compare with state t+1 (one-step error)",
    )
    p.add_argument("--resync", type=int, default=None, metavar="K",
                   help="with --mode actions: restore the recorded state every K steps")
    p.add_argument("--episodes", action=GivenOnce, default=None, metavar="LIST",
                   help="episodes to replay of every recording, e.g. 0,3-7 (default: all)")
    p.add_argument("--report", default=None, metavar="REPORT.json",
                   help="stream every verdict into REPORT.jsonl as it comes and write the report REPORT.json")
    p.add_argument("--resume", default=None, metavar="REPORT.json",
                   help="finish the run that wrote REPORT.json (interrupted, killed): replay only the episodes it "
                        "has no verdict for, with its recordings and options (not a run with -o)")
    p.add_argument("-o", "--output", default=None, metavar="REPLAYED",
                   help="write the replayed episodes of one recording (.h5/.mcap)")
    p.add_argument("--overwrite", action="store_true", help="replace the -o and --report files if they exist")
    p.add_argument("--obs-mode", default=None,
                   help="observation mode of the replay (e.g. rgb with --mode states -o OUT to re-render)")
    p.add_argument("--sim-backend", default=None,
                   help="replay on another sim backend than the recorded one (physx_cpu, physx_cuda); a GPU "
                        "recording on a machine without CUDA: physx_cpu (another engine, so the verdict is not exact)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="parallel processes, or Ray actors with --ray (default 1)")
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="replay on a Ray cluster (pip install 'simreel[ray]'): alone, a cluster started on this "
                        "machine; 'auto', the cluster this machine belongs to; or its address (host:6379, "
                        "ray://host:10001)")
    p.add_argument("--ship", action="store_true",
                   help="with --ray: send every episode from this machine to the workers (by default they read the "
                        "recordings they see as this machine does, on a shared filesystem, and get the rest sent)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_import_option(p)
    p.set_defaults(run=run, resumed_defaults={dest: p.get_default(dest) for dest in _VERDICT_FLAGS})


_VERDICT_FLAGS = ("mode", "atol", "tol", "resync", "episodes", "report", "output", "overwrite", "obs_mode",
                  "sim_backend", "imports")
"""Options a resumed run takes from its report."""


def _build_run(args: argparse.Namespace) -> Any:
    from simreel.replay.verify import ReplayOptions, ReplayRun

    if args.resume is not None:
        changed = [k for k in _VERDICT_FLAGS if getattr(args, k) != args.resumed_defaults[k]]
        if args.paths or changed:
            what = "PATH" if args.paths else "--" + changed[0].replace("_", "-")
            raise UsageError(f"--resume takes the recordings and options from the report; drop {what} (only "
                             "--workers, --ray, --ship and -q may change)")
        return ReplayRun.resume(args.resume, workers=args.workers, ray=args.ray, ship=args.ship,
                                command=args.command_line)
    if not args.paths:
        raise UsageError("name the recordings to replay (files, folders, patterns), or --resume REPORT.json")
    episodes = None if args.episodes is None else parse_index_ranges(args.episodes)
    if episodes is not None and not episodes:
        raise UsageError(f"--episodes {args.episodes!r} names no episode")
    options = ReplayOptions(mode=args.mode, resync=args.resync, episodes=episodes, atol=args.atol,
                            group_tolerances=dict(args.tol), output=args.output, overwrite=args.overwrite,
                            obs_mode=args.obs_mode, workers=args.workers, imports=args.imports,
                            sim_backend=args.sim_backend, command=args.command_line, report=args.report, ray=args.ray,
                            ship=args.ship)
    return ReplayRun(args.paths, options)


def run(args: argparse.Namespace) -> int:
    from simreel.formats.inputs import shown_path

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
    except KeyboardInterrupt:
        if replay.report_json is not None or replay.options.output is not None:
            sys.stderr.write(f"simreel replay: {replay.how_to_finish()}\n")
        raise
    _print(tally, replay)
    return tally.exit_status()


def _print(tally: Any, replay: Any) -> None:
    from simreel.formats.inputs import shown_path

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
