"""Time to build a Rerun .rrd of one long episode once the env is built (target: ≤ 1 s for 1000 steps).

Records one `--steps`-step episode of `--env` (random actions, contacts "auto") into a temporary folder,
once with body poses and once without, rebuilds the env for viewing (not timed), then times
`build_session(path, env=env)` + `session.save(out)` — reading the episode, resetting to its scene,
reading the geometry, computing or reading every body's pose at every step, logging everything with
`send_columns`, and writing the .rrd — `--repeat` times, printing the best:

    .venv/bin/python benchmarks/bench_view.py                    # PickCube-v1, 1000 steps, collision shapes
    .venv/bin/python benchmarks/bench_view.py --geometry visual  # visual meshes (needs a render device)

"poses recorded" reads the poses from the file; "poses restored" restores each recorded state into the env
and reads every body's pose (what a recording made without --poses needs).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path


def record(env_id: str, steps: int, path: Path, *, poses: bool) -> None:
    import numpy as np
    import torch

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    env = make_env(env_id, render_backend="none", max_episode_steps=steps)
    rec = RecordWrapper(env, path, poses=poses, overwrite=True)
    rec.reset(seed=0)
    u = env.unwrapped
    rng = np.random.default_rng(0)
    space = u.single_action_space
    for _ in range(steps):
        rec.step(torch.from_numpy(rng.uniform(space.low, space.high).astype(np.float32)[None] * 0.3))
    rec.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="PickCube-v1")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--geometry", default="collision", choices=("collision", "visual", "auto"))
    args = parser.parse_args(argv)

    import rerun  # noqa: F401  (its import, ~0.5 s, is not part of building a session)

    from simreel.formats import open_reader
    from simreel.viewers import build_session, rebuild_env

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = {"poses recorded": folder / "with_poses.h5", "poses restored": folder / "no_poses.h5"}
        t0 = time.perf_counter()
        record(args.env, args.steps, paths["poses recorded"], poses=True)
        record(args.env, args.steps, paths["poses restored"], poses=False)
        print(f"recorded 2 × {args.steps} steps of {args.env} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        with open_reader(paths["poses recorded"]) as r:
            meta = r.meta
        t0 = time.perf_counter()
        env = rebuild_env(meta, geometry=args.geometry)
        env_s = time.perf_counter() - t0
        print(f"{args.env}, {args.steps} steps, {args.geometry} geometry; env rebuilt in {env_s:.2f} s (not counted)")
        print(f"{'case':<16} {'best s':>7} {'prepare':>8} {'log+write':>10} {'rrd MiB':>8}")
        for label, path in paths.items():
            best = None
            for _ in range(args.repeat):
                out = folder / f"{path.stem}.rrd"
                t0 = time.perf_counter()
                session = build_session(path, env=env, geometry=args.geometry)
                t1 = time.perf_counter()
                session.save(out, overwrite=True)
                t2 = time.perf_counter()
                if best is None or t2 - t0 < best[0]:
                    best = (t2 - t0, t1 - t0, t2 - t1, out.stat().st_size / 2**20)
            total, prep, log, size = best
            print(f"{label:<16} {total:>7.3f} {prep:>8.3f} {log:>10.3f} {size:>8.1f}")
        env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
