"""What ManiSkill RecordEpisode files with unseeded resets replay as: their stale seeds found, and their verdicts.

Usage: python benchmarks/maniskill_stale_seeds.py [--episodes 6] [--steps 40] [--tasks PickCube-v1 ...]

For each task (default PickCube-v1, PushCube-v1, StackCube-v1; `pd_joint_delta_pos`, state observations), records
with ManiSkill's own `RecordEpisode` (record_env_state=True) one reset with seed 0, then `--episodes` - 1 resets
without one (as an RL loop resets), `--steps` random actions each (torch's generator seeded 0, as a policy samples),
then `verify_recording` (mode actions) and counts, over the unseeded episodes: those whose `episode_seed` was found
stale (its reset did not remake env_states[0]) and their verdicts.
"""

from __future__ import annotations

import argparse
import tempfile
from collections import Counter
from pathlib import Path


def record(folder: Path, env_id: str, shape: tuple[int, int]) -> Path:
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401
    import torch
    from mani_skill.utils.wrappers.record import RecordEpisode

    from simreel.sim.make import prepare_plain_gym_make

    prepare_plain_gym_make()  # the software Vulkan driver on a CPU machine
    episodes, steps = shape
    env = RecordEpisode(gym.make(env_id, obs_mode="state", control_mode="pd_joint_delta_pos"), str(folder),
                        trajectory_name=env_id, save_video=False, record_env_state=True)
    torch.manual_seed(0)
    for e in range(episodes):
        env.reset(seed=0) if e == 0 else env.reset()
        for _ in range(steps):
            env.step(torch.rand(env.action_space.shape) * 2 - 1)
    env.close()
    return folder / f"{env_id}.h5"


def main() -> None:
    from simreel.replay import verify_recording

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=6)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--tasks", nargs="+", default=["PickCube-v1", "PushCube-v1", "StackCube-v1"])
    args = ap.parse_args()
    total: Counter = Counter()
    with tempfile.TemporaryDirectory() as tmp:
        for env_id in args.tasks:
            path = record(Path(tmp), env_id, (args.episodes, args.steps))
            unseeded = verify_recording(path).episodes[1:]
            stale = sum(any(x.startswith("stale seed") for x in e.limits) for e in unseeded)
            verdicts = Counter(e.verdict for e in unseeded)
            total.update(verdicts)
            print(f"{env_id}: {len(unseeded)} unseeded episodes, {stale} stale seeds found; {dict(verdicts)}")
    print(f"all: {dict(total)}")


if __name__ == "__main__":
    main()
