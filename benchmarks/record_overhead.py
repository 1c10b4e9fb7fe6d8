"""Recording overhead: RecordWrapper.step vs bare env.step, measured in one run, and bytes per step.

Usage: python benchmarks/record_overhead.py [--env PickCube-v1] [--episodes 100] [--contacts auto|none]
                                           [--poses] [--format h5|mcap]

A bare env and a recorded one step the same actions from the same seeds, interleaved episode by
episode so machine noise hits both alike. The step() ratio times step() alone; the end-to-end ratio
adds the resets, where the recorder commits each finished episode to the file.
Target (issue 2): ≤ 1.10× for PickCube-v1, state obs, contacts on.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env


def _episode(env, seed, actions) -> tuple[float, float, float]:
    """(wall seconds in step(), CPU seconds in step(), wall seconds of the reset that starts it)."""
    t = time.perf_counter()
    env.reset(seed=seed)  # for the recorder this also commits the previous episode
    reset = time.perf_counter() - t
    w, c = time.perf_counter(), time.process_time()
    for a in actions:
        env.step(a)
    return time.perf_counter() - w, time.process_time() - c, reset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="PickCube-v1")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--contacts", default="auto")
    ap.add_argument("--poses", action="store_true")
    ap.add_argument("--format", default="h5", choices=["h5", "mcap"])
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    bare = make_env(args.env, obs_mode="state", max_episode_steps=args.steps)
    shape = bare.action_space.shape
    actions = np.random.default_rng(0).uniform(-1, 1, size=(args.episodes, args.steps, *shape)).astype(np.float32)
    path = Path(tempfile.mkdtemp()) / f"r.{args.format}"
    rec = RecordWrapper(make_env(args.env, obs_mode="state", max_episode_steps=args.steps), path,
                        contacts=args.contacts, poses=args.poses)
    for env in (bare, rec):  # warm-up: first steps build caches, the first commit creates the file's layout
        _episode(env, 10_000, actions[0])
    totals = np.zeros((2, 3))
    per_episode = []
    for k in range(args.episodes):  # interleaved episode by episode, so machine noise hits both alike
        b = _episode(bare, k, actions[k])
        r = _episode(rec, k, actions[k])
        totals += [b, r]
        per_episode.append(r[0] / b[0])
    t = time.perf_counter()
    rec.close()
    close = time.perf_counter() - t
    steps = args.episodes * args.steps
    (bw, bc, br), (rw, rc, rr) = totals
    size = path.stat().st_size
    print(f"{args.env}, state obs, contacts={args.contacts}, poses={args.poses}, format={args.format}: "
          f"{args.episodes} episodes × {args.steps} steps, bare and recorded interleaved per episode")
    print(f"  bare env.step        {bw / steps * 1e6:8.1f} µs/step wall, {bc / steps * 1e6:8.1f} µs/step CPU")
    print(f"  recorded step        {rw / steps * 1e6:8.1f} µs/step wall, {rc / steps * 1e6:8.1f} µs/step CPU")
    print(f"  step() ratio         {rw / bw:8.3f}× wall, {rc / bc:.3f}× CPU "
          f"(per-episode wall ratios: median {statistics.median(per_episode):.3f})")
    print(f"  end-to-end ratio     {(rw + rr) / (bw + br):8.3f}× wall (resets, which commit episodes, included)")
    print(f"  file size            {size / ((args.episodes + 1) * args.steps):8.1f} bytes/step "
          f"({size} bytes; close {close * 1e3:.0f} ms incl. env.close)")


if __name__ == "__main__":
    main()
