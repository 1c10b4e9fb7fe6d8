"""`simreel video`: an mp4 per episode of a recording, optionally side by side with its replay or conversion."""

from __future__ import annotations

import argparse
from typing import Any

from simreel.cli.common import (
    QUIET,
    GivenOnce,
    add_import_option,
    mode_choices,
    parse_index_ranges,
    parse_size,
    progress_bar,
    refuse_tolerances_without_compare,
)
from simreel.errors import UsageError
from simreel.options.declare import add_option

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "video",
        help="write an mp4 per episode (optionally beside its replay, its conversion or another recording)",
        description="Write FOLDER/<name>_ep<N>.mp4 for each episode: one frame per state (steps + 1 frames), the "
        "step drawn in. Frames are rendered from the recorded states (a render device is needed: a GPU or the "
        "software Vulkan `make setup` fetches), or taken from a recorded camera (--camera). With --compare, the "
        "other recording's episode is drawn on the right with the verdict of its conversion or of comparing the "
        "two, said of what it is: `replay` (simreel replay -o of PATH), `conversion`, else its file name.",
    )
    p.add_argument("path", metavar="PATH", help="a recording (.h5 or .mcap; simreel's or ManiSkill's)")
    p.add_argument("-o", "--output", default=".", metavar="FOLDER", help="folder for the videos (default: here)")
    p.add_argument("--episodes", action=GivenOnce, default=None, metavar="LIST", help="episodes, e.g. 0,3-7 (default: all)")
    p.add_argument("--compare", default=None, metavar="OTHER",
                   help="another recording of the task, drawn on the right: a replay (simreel replay -o) or "
                        "conversion (simreel convert) of PATH, or a second recording")
    p.add_argument("--size", type=parse_size, default=None, metavar="WxH",
                   help="frame size, even numbers (default 256x256, 512x256 side by side)")
    p.add_argument("--camera", default=None, metavar="NAME", help="use the recorded rgb images of this camera")
    p.add_argument("--fps", type=float, default=None,
                   help="frames per second, a positive number (default: the control frequency)")
    p.add_argument("--mode", choices=mode_choices(), default=None,
                   help="whose default tolerances judge the file given with --compare (as simreel replay --mode); "
                        "default: a replay or conversion of PATH is judged with the tolerances that judged it when "
                        "it was written, any other file with actions'")
    p.add_argument("--overwrite", action="store_true", help="replace existing videos")
    add_option(p, "quiet", QUIET, False)
    add_import_option(p, reads_recordings=True)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from simreel.viewers.video import VideoOptions, VideoRun

    refuse_tolerances_without_compare(args)
    episodes = None if args.episodes is None else parse_index_ranges(args.episodes)
    if episodes is not None and not episodes:
        raise UsageError(f"--episodes {args.episodes!r} names no episode")
    size = args.size or ((512, 256) if args.compare else (256, 256))
    options = VideoOptions(episodes=episodes, compare=args.compare, size=size,
                           camera=args.camera, fps=args.fps, mode=args.mode, overwrite=args.overwrite,
                           imports=tuple(args.imports), trust_recorded_imports=args.trust_recorded_imports)
    videos = VideoRun(args.path, args.output, options)  # bad files, episodes and targets fail here
    try:
        with progress_bar(quiet=args.quiet, total=videos.frames, unit="frame", desc="video") as bar:
            videos.execute(bar.update)
    finally:  # a stop or an error: the videos written before it are named too
        for v in videos.written:
            print(f"episode {v.index}: {v.path} ({v.frames} frames{', ' + v.verdict if v.verdict else ''})")
        for note in videos.notes:
            print(f"note: {note}")
    damaged = videos.damage_error()
    if damaged is not None:  # never left out silently
        raise damaged
    return 0
