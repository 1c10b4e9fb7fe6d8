"""Child process for the kill -9 tests: records PickCube-v1 episodes forever into argv[1]."""

import sys

import numpy as np

from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env

env = RecordWrapper(make_env("PickCube-v1"), sys.argv[1], contacts="auto")
rng = np.random.default_rng(0)
seed = 0
while True:
    env.reset(seed=seed)
    for _ in range(50):
        env.step(rng.uniform(-1, 1, size=env.action_space.shape).astype(np.float32))
    seed += 1
