"""Child process of the kill -9 test: records PickCube episodes to an MCAP file until it is killed.

Usage: python mcap_kill_child.py OUT.mcap EPISODES STEPS. Records EPISODES episodes of STEPS steps
(seed k, actions from `episode_actions(k, STEPS)`), prints `committed N` once N episodes are committed,
then starts one more episode, prints `running` after STEPS // 2 of its steps and waits to be killed.
Small blocks and chunks make part of the running episode reach the file before the kill.
"""

from __future__ import annotations

import sys
import time

import numpy as np


def episode_actions(seed: int, steps: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (steps, 8)).astype(np.float32)


def main(out: str, episodes: int, steps: int) -> None:
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    rec = RecordWrapper(make_env("PickCube-v1"), out, poses=True, block_steps=4,
                        writer_options={"chunk_size": 2048})
    for k in range(episodes + 1):
        rec.reset(seed=k)
        if k == episodes:
            print(f"committed {len(rec.episodes_committed)}", flush=True)
        for t, action in enumerate(episode_actions(k, steps)):
            rec.step(action)
            if k == episodes and t + 1 == steps // 2:
                print("running", flush=True)
                time.sleep(300)  # killed here
    rec.close()  # not reached in the test


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
