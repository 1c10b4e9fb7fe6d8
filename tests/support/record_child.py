"""Child process of the fault tests: records PickCube-v1 episodes into a file and says when each is committed.

Usage: python record_child.py OUT [--overwrite] [--episodes N] [--steps T] [--record-obs] [--format-options JSON]

Records N episodes (default: until it is killed) of T steps (default 50; seed k, random actions from
`episode_actions(k, T)`) and prints `committed K` (flushed) each time an episode has been committed, then
`done` after `close()`.
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def episode_actions(seed: int, steps: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (steps, 8)).astype(np.float32)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("out")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--episodes", type=int, default=None)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--record-obs", action="store_true")
    p.add_argument("--writer-options", type=json.loads, default={})
    args = p.parse_args()

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    rec = RecordWrapper(make_env("PickCube-v1", max_episode_steps=args.steps), args.out, overwrite=args.overwrite,
                        record_obs=args.record_obs, writer_options=args.writer_options)
    k = 0
    while args.episodes is None or k < args.episodes:
        rec.reset(seed=k)
        if k:
            print(f"committed {len(rec.episodes_committed)}", flush=True)
        for action in episode_actions(k, args.steps):
            rec.step(action)
        k += 1
    rec.close()
    print(f"committed {len(rec.episodes_committed)}", flush=True)
    print("done", flush=True)


if __name__ == "__main__":
    main()
