"""Recording overhead: RecordWrapper.step vs bare env.step, measured in one run, and bytes per step.

Usage: python benchmarks/record_overhead.py [--env PickCube-v1] [--episodes 20] [--rounds 5] [--contacts auto]

Bare and recorded envs step the same actions from the same seeds, in alternating rounds so machine
noise hits both alike; the ratio is the median over rounds of (recorded time / bare time). Only
step() is timed: resets and the final commit are excluded (commit cost is reported separately).
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

from simreel.envs import make_env


def _rollout(env, actions, seeds) -> tuple[float, float]:
    """(seconds in step() alone, seconds end to end incl. resets, which commit finished episodes)."""
    stepping = 0.0
    t0 = time.perf_counter()
    for seed, acts in zip(seeds, actions, strict=True):
        env.reset(seed=seed)
        t = time.perf_counter()
        for a in acts:
            env.step(a)
        stepping += time.perf_counter() - t
    env.reset(seed=seeds[0])  # commits the last episode
    return stepping, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="PickCube-v1")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--contacts", default="auto")
    ap.add_argument("--poses", action="store_true")
    ap.add_argument("--format", default="h5", choices=["h5", "mcap"])
    args = ap.parse_args()

    bare = make_env(args.env, obs_mode="state", max_episode_steps=args.steps)
    rng = np.random.default_rng(0)
    shape = bare.action_space.shape
    actions = rng.uniform(-1, 1, size=(args.episodes, args.steps, *shape)).astype(np.float32)
    seeds = list(range(args.episodes))
    tmp = Path(tempfile.mkdtemp())
    ratios, e2e_ratios, bare_times, rec_times = [], [], [], []
    _rollout(bare, actions[:2], seeds[:2])  # warm-up
    for k in range(args.rounds):
        rec = RecordWrapper(make_env(args.env, obs_mode="state", max_episode_steps=args.steps),
                            tmp / f"r{k}.{args.format}", contacts=args.contacts, poses=args.poses)
        _rollout(rec, actions[:2], seeds[:2])  # warm-up (first episodes create the file's datasets)
        tb, eb = _rollout(bare, actions, seeds)
        tr, er = _rollout(rec, actions, seeds)
        rec.close()
        ratios.append(tr / tb)
        e2e_ratios.append(er / eb)
        bare_times.append(tb)
        rec_times.append(tr)
    steps = args.episodes * args.steps
    size = (tmp / f"r0.{args.format}").stat().st_size
    recorded_steps = (args.episodes + 2) * args.steps
    print(f"{args.env}, state obs, contacts={args.contacts}, poses={args.poses}, format={args.format}: "
          f"{args.rounds} rounds × {steps} steps")
    print(f"  bare env.step      {statistics.median(bare_times) / steps * 1e6:8.1f} µs/step")
    print(f"  recorded step      {statistics.median(rec_times) / steps * 1e6:8.1f} µs/step")
    print(f"  step() ratio       {statistics.median(ratios):8.3f}×  (rounds: {', '.join(f'{r:.3f}' for r in ratios)})")
    print(f"  end-to-end ratio   {statistics.median(e2e_ratios):8.3f}×  (resets and episode commits included; "
          f"rounds: {', '.join(f'{r:.3f}' for r in e2e_ratios)})")
    print(f"  file size          {size / recorded_steps:8.1f} bytes/step ({size} bytes, {recorded_steps} steps)")


if __name__ == "__main__":
    main()
