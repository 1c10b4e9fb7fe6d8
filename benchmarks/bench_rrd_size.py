"""Bytes of a Rerun session (`simreel view --save`) of one PickCube-v1 episode, with the meshes compacted as `simreel
view` logs them (`simreel.viewers.mesh_compaction`) and as they were logged before (every mesh as the scene gives it),
side by side in one run; and what they are made of: the static geometry (logged once) and the bytes each step adds.

    .venv/bin/python benchmarks/bench_rrd_size.py                  # 50- and 100-step episodes, visual meshes
    .venv/bin/python benchmarks/bench_rrd_size.py --compare        # with the replay beside it, as --compare does

A step's bytes are (size at 2N steps - size at N steps) / N; the static part is what is left of the N-step size.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path


def _record(env_id: str, steps: int, path: Path) -> None:
    from simreel.cli.main import main

    assert main(["record", env_id, "-o", str(path), "--max-steps", str(steps), "--seed", "0", "-q"]) == 0


def _size(path: Path, out: Path, *, compare: bool, compacted: bool) -> int:
    import simreel.viewers.log_scene as log_scene
    from simreel.viewers import build_session
    from simreel.viewers.mesh_compaction import compact_mesh

    log_scene.compact_mesh = compact_mesh if compacted else (lambda part: part)
    session = build_session(path, episode=0, compare=path if compare else None)
    session.save(out, overwrite=True)
    return out.stat().st_size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="PickCube-v1")
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--compare", action="store_true", help="the replay beside the recording (its ghost)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        short, long = folder / "short.h5", folder / "long.h5"
        _record(args.env, args.steps, short)
        _record(args.env, 2 * args.steps, long)
        print(f"{args.env}, one episode of {args.steps} steps{' beside its replay' if args.compare else ''}")
        print(f"{'meshes':<12} {'KiB/episode':>12} {'static KiB':>11} {'bytes/step':>11}")
        sizes = {}
        for label, compacted in (("as given", False), ("compacted", True)):
            n = _size(short, folder / "short.rrd", compare=args.compare, compacted=compacted)
            n2 = _size(long, folder / "long.rrd", compare=args.compare, compacted=compacted)
            per_step = (n2 - n) / args.steps
            sizes[label] = n
            print(f"{label:<12} {n / 1024:>12.0f} {(n - per_step * args.steps) / 1024:>11.0f} {per_step:>11.0f}")
        print(f"compacted / as given: {sizes['compacted'] / sizes['as given']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
