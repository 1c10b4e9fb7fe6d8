"""What committing one episode to an HDF5 recording costs, early and late in a long recording, with the writer's
bounded metadata cache and with HDF5's default one, side by side in one run.

Records one `--steps`-step episode of `--env` (random actions, contacts "auto", as `simreel record` does), then
writes it `--episodes` times through two `Hdf5Writer`s at once, interleaved commit by commit so machine noise hits
both alike: one as simreel writes (its metadata cache bounded, `simreel.formats.hdf5.writer._bound_metadata_cache`),
one whose file handle is given back HDF5's default cache (it grows to 2 MB, and every flush walks it). Prints the
median time of `begin_episode` + `append` and of `commit` over the first and the last 50 episodes, then the time to
open each finished file and read every episode (a reader has its own cache; the writer's setting is not stored).
Both writers share one process, so the late figures of each include some of the other's cost (measured alone, the
bounded writer's commit went 4.35 → 4.65 ms over 2,000 episodes, against 4.59 → 5.68 ms here):

    .venv/bin/python benchmarks/bench_commit.py                   # PickCube-v1, 50 steps, 2000 episodes
    .venv/bin/python benchmarks/bench_commit.py --episodes 500

Target (issue 17): the commit is the recorder's largest per-episode cost (end-to-end overhead ≤ 1.05×,
`benchmarks/record_overhead.py`); it must not grow with the file.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
import time
from pathlib import Path

_WINDOW = 50


def record_one(env_id: str, steps: int, path: Path) -> None:
    import numpy as np
    import torch

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    env = make_env(env_id, render_backend="none", max_episode_steps=steps)
    rec = RecordWrapper(env, path, contacts="auto")
    rec.reset(seed=0)
    space = env.unwrapped.single_action_space
    rng = np.random.default_rng(0)
    for _ in range(steps):
        rec.step(torch.from_numpy(rng.uniform(space.low, space.high).astype(np.float32)[None]))
    rec.close()


def default_cache_config():
    """HDF5's default metadata cache configuration (that of a fresh in-memory file)."""
    import h5py

    with h5py.File("default", "w", driver="core", backing_store=False) as f:
        return f.id.get_mdc_config()


def commit_times(source: Path, folder: Path, episodes: int) -> dict[str, dict[str, list[float]]]:
    """Seconds per begin (+ append) and per commit of each variant, commit by commit."""
    from simreel.formats import open_reader
    from simreel.formats.hdf5.writer import Hdf5Writer

    with open_reader(source) as r:
        episode, meta = r.read_episode(r.episodes[0].index), r.meta
    writers = {"bounded cache (simreel)": Hdf5Writer(folder / "bounded.h5", meta),
               "HDF5 default cache": Hdf5Writer(folder / "default.h5", meta)}
    writers["HDF5 default cache"]._file.id.set_mdc_config(default_cache_config())
    times = {name: {"begin": [], "commit": []} for name in writers}
    reset, steps = episode.reset_block(), episode.steps_block()
    for i in range(episodes):
        ep_meta = dataclasses.replace(episode.meta, index=i)
        for name, w in writers.items():
            t0 = time.perf_counter()
            sink = w.begin_episode(ep_meta, reset)
            sink.append(steps)
            t1 = time.perf_counter()
            sink.commit(ep_meta)
            times[name]["begin"].append(t1 - t0)
            times[name]["commit"].append(time.perf_counter() - t1)
    for w in writers.values():
        w.close()
    return times


def read_all(path: Path) -> float:
    from simreel.formats import open_reader

    t = time.perf_counter()
    with open_reader(path) as r:
        for m in r.episodes:
            r.read_episode(m.index)
    return time.perf_counter() - t


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="PickCube-v1")
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--reads", type=int, default=3, help="reads of each finished file (the best is printed)")
    args = parser.parse_args(argv)
    if args.episodes < 2 * _WINDOW:
        parser.error(f"--episodes must be at least {2 * _WINDOW}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        record_one(args.env, args.steps, folder / "source.h5")
        times = commit_times(folder / "source.h5", folder, args.episodes)
        print(f"{args.env}, {args.steps}-step episodes, {args.episodes} commits per writer, interleaved; "
              f"median ms of episodes 1-{_WINDOW} | {args.episodes - _WINDOW + 1}-{args.episodes}:")
        for name, t in times.items():
            row = "  ".join(f"{part} {statistics.median(t[part][:_WINDOW]) * 1e3:5.2f} | "
                            f"{statistics.median(t[part][-_WINDOW:]) * 1e3:5.2f}" for part in ("begin", "commit"))
            print(f"  {name:24s} {row}")
        bounded, default = (statistics.median(t["commit"][-_WINDOW:]) for t in times.values())
        print(f"  last {_WINDOW} commits, bounded / default: {bounded / default:.2f}x")
        reads = {name: [] for name in ("bounded.h5", "default.h5")}
        for _ in range(args.reads):
            for name in reads:
                reads[name].append(read_all(folder / name))
        print(f"reading every episode back (best of {args.reads}): "
              + ", ".join(f"{name} {min(t):.2f} s" for name, t in reads.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
