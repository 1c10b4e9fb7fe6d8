"""`simreel recover`: rescue the committed episodes of an MCAP recording whose process was killed.

A recording process that dies (kill -9, crash, power cut) leaves an MCAP file without summary and
footer, which `inspect`/`replay`/`view` refuse. `recover` reads it front to back, writes every
committed episode into a complete file (in place unless `-o` is given) and reports what was lost: the
episodes still running at the time and any record cut in the middle. HDF5 recordings need no recovery
(their committed episodes stay readable); `recover` says so.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from simreel.errors import UsageError

__all__ = ["add_parser", "run", "recover"]


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


def recover(path: str | Path, output: str | Path | None = None, *, overwrite: bool = False) -> dict[str, Any]:
    """Rewrite the committed episodes of `path` into `output` (default: `path` itself, atomically).

    Returns a report: `complete` (nothing to do), `episodes`, `steps`, `unfinished`, `lost_bytes`, `output`.
    """
    from simreel.formats import check_writable, format_of, open_writer, remove_recording
    from simreel.formats.mcap import McapReader

    src = Path(path)
    if format_of(src) != "mcap":
        raise UsageError(f"{src}: only MCAP recordings need recovery; an HDF5 recording keeps its committed "
                         "episodes readable (inspect lists the unfinished ones)")
    if output is not None and Path(output).resolve() != src.resolve():
        check_writable(output, overwrite=overwrite)  # refuse OUT before reading PATH front to back
    with McapReader(src, recover=True) as reader:
        report: dict[str, Any] = {
            "complete": not reader.recovered and not reader.unfinished,
            "episodes": len(reader.episodes),
            "steps": sum(e.length for e in reader.episodes),
            "unfinished": list(reader.unfinished),
            "lost_bytes": reader.lost_bytes,
            "output": None,
        }
        if report["complete"] and output is None:
            return report
        dst = Path(output) if output is not None else src.with_name(src.stem + ".recovering.mcap")
        if output is not None:
            format_of(dst)
            if dst.resolve() == src.resolve():
                dst, output = src.with_name(src.stem + ".recovering.mcap"), None
        # Built outside the try: a writer that refuses OUT (it exists, another recording writes it) has
        # created nothing, and what is there is not this call's to delete.
        writer = open_writer(dst, reader.meta, overwrite=overwrite or output is None)
        try:
            with writer:
                for m in reader.episodes:
                    writer.write_episode(reader.read_episode(m.index))
        except BaseException:
            remove_recording(dst)
            raise
    if output is None:
        os.replace(dst, src)
        dst = src
    report["output"] = str(dst)
    return report


def run(args: argparse.Namespace) -> int:
    r = recover(args.path, args.output, overwrite=args.overwrite)
    if r["complete"] and r["output"] is None:
        print(f"{args.path} is complete ({r['episodes']} episode(s), {r['steps']} steps): nothing to recover")
        return 0
    print(f"recovered {r['episodes']} committed episode(s), {r['steps']} steps, into {r['output']}")
    lost = list(r["unfinished"])
    if r["lost_bytes"]:
        lost.append(f"{r['lost_bytes']} byte(s) of a record cut short at the end of the file")
    if lost:
        print("lost (never committed): " + "; ".join(lost))
    else:
        print("lost: nothing (every episode that began was committed)")
    return 0
