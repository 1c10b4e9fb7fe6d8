"""Bytes per step and write cost of the HDF5 and MCAP writers, measured in one run on the same episodes.

Records `--episodes` episodes of `--env` once (random actions, contacts "auto", body poses on) into
memory, then writes them with each writer configuration, `--repeat` times, and prints the best time:

    .venv/bin/python benchmarks/bench_formats.py --episodes 20 --steps 50

`write µs/step` is the wall time of `write_episode` for every episode plus opening and closing the
file, divided by the steps written; each episode is committed (made durable) as the recorder would.
`read µs/step` reads every episode back. `--record` also times whole recording loops (env step
included) with no recorder, and with RecordWrapper into .h5 and .mcap. MCAP holds the exact arrays *and* the viewable channels
(/tf with every body's pose each step, /plots, /log), so it writes more than HDF5 by design.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

CONFIGS: list[tuple[str, str, dict[str, Any]]] = [
    ("hdf5 lzf (default)", ".h5", {}),
    ("hdf5 uncompressed", ".h5", {"compression": None}),
    ("mcap zstd 1 MiB chunks (default)", ".mcap", {}),
    ("mcap zstd 256 KiB chunks", ".mcap", {"chunk_size": 256 << 10}),
    ("mcap zstd 4 MiB chunks", ".mcap", {"chunk_size": 4 << 20}),
    ("mcap lz4 1 MiB chunks", ".mcap", {"compression": "lz4"}),
    ("mcap uncompressed", ".mcap", {"compression": "none"}),
]


def record_in_memory(env_id: str, episodes: int, steps: int, folder: Path) -> tuple[Any, list[Any]]:
    """Record through RecordWrapper (HDF5, poses on) and read everything back into memory."""
    import numpy as np

    from simreel.formats import open_reader
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    path = folder / "source.h5"
    rec = RecordWrapper(make_env(env_id), path, poses=True)
    rng = np.random.default_rng(0)
    try:
        for k in range(episodes):
            rec.reset(seed=k)
            for _ in range(steps):
                rec.step(rng.uniform(-1, 1, rec.action_space.shape).astype(np.float32))
    finally:
        rec.close()
    with open_reader(path) as reader:
        return reader.meta, [reader.read_episode(m.index) for m in reader.episodes]


def measure(meta: Any, episodes: list[Any], variant: tuple[str, dict[str, Any]], folder: Path,
            repeat: int) -> tuple[float, float, int]:
    """(best write seconds, best read seconds, file bytes)."""
    from simreel.formats import open_reader, open_writer

    suffix, options = variant
    best_write = best_read = float("inf")
    size = 0
    for r in range(repeat):
        path = folder / f"bench_{r}{suffix}"
        t0 = time.perf_counter()
        with open_writer(path, meta, overwrite=True, **options) as writer:
            for ep in episodes:
                writer.write_episode(ep)
        best_write = min(best_write, time.perf_counter() - t0)
        size = path.stat().st_size
        t0 = time.perf_counter()
        with open_reader(path) as reader:
            for m in reader.episodes:
                reader.read_episode(m.index)
        best_read = min(best_read, time.perf_counter() - t0)
    return best_write, best_read, size


def record_cost(env_id: str, episodes: int, steps: int, folder: Path) -> list[tuple[str, float]]:
    """µs/step of a whole recording loop (env step included): no recorder, then RecordWrapper per format."""
    import numpy as np

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    out = []
    for name, suffix, poses in (("env only (no recorder)", None, None), ("record .h5", ".h5", False),
                                ("record .h5 --poses", ".h5", True), ("record .mcap (poses on)", ".mcap", True)):
        env = make_env(env_id)
        rec = env if suffix is None else RecordWrapper(env, folder / f"rec{suffix}", poses=poses, overwrite=True)
        rng = np.random.default_rng(0)
        t0 = time.perf_counter()
        for k in range(episodes):
            rec.reset(seed=k)
            for _ in range(steps):
                rec.step(rng.uniform(-1, 1, rec.action_space.shape).astype(np.float32))
        rec.close()
        out.append((name, (time.perf_counter() - t0) / (episodes * steps) * 1e6))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="PickCube-v1")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--record", action="store_true", help="also time whole recording loops per format")
    args = p.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="simreel-bench-"))
    try:
        t0 = time.perf_counter()
        meta, episodes = record_in_memory(args.env, args.episodes, args.steps, folder)
        steps = sum(ep.length for ep in episodes)
        print(f"{args.env}: {len(episodes)} episodes, {steps} steps, {len(meta.pose_bodies)} bodies, "
              f"{len(meta.contact_channels)} contact channels (recorded in {time.perf_counter() - t0:.1f} s); "
              f"best of {args.repeat}")
        print(f"{'writer':<34} {'bytes/step':>10} {'write µs/step':>14} {'read µs/step':>13}")
        for name, suffix, options in CONFIGS:
            write_s, read_s, size = measure(meta, episodes, (suffix, options), folder, args.repeat)
            print(f"{name:<34} {size / steps:>10.0f} {write_s / steps * 1e6:>14.1f} {read_s / steps * 1e6:>13.1f}")
        if args.record:
            print(f"\n{'recording loop':<34} {'µs/step':>10}")
            for name, us in record_cost(args.env, args.episodes, args.steps, folder):
                print(f"{name:<34} {us:>10.0f}")
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
