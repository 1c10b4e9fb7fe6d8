"""ManiSkill trajectory files made with ManiSkill's own tools, the way its users' datasets are made.

- `record_maniskill`: `mani_skill.utils.wrappers.RecordEpisode` around a plain ``gym.make`` env, driven in
  ``pd_joint_pos`` (the control mode of ManiSkill's published demos) along a smooth random path of joint
  targets, like a motion-planned demo; obs mode, env states and rewards as asked.
- `replay_maniskill`: `python -m mani_skill.trajectory.replay_trajectory` on such a file in a child process
  (it needs a render device: pass an environment with lavapipe), returning the file it wrote.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["record_maniskill", "replay_maniskill", "joint_targets"]


def joint_targets(q0: np.ndarray, low: np.ndarray, high: np.ndarray, steps: int, seed: int) -> np.ndarray:
    """(steps, A) joint-position targets: from the robot's pose at reset, a smooth random walk within ±15% of
    each joint's range, inside the limits."""
    rng = np.random.default_rng(seed)
    span = (high - low).astype(np.float64)
    walk = np.cumsum(rng.normal(0.0, 0.02, (steps, len(q0))), axis=0)
    walk = np.clip(walk, -0.15, 0.15) * span
    return np.clip(q0 + walk, low, high).astype(np.float32)


def _start_targets(env: Any) -> np.ndarray:
    """The joint targets that hold the robot where the reset put it (its qpos, one per action dimension)."""
    qpos = np.asarray(env.unwrapped.agent.robot.get_qpos())[0]
    return qpos[: env.action_space.shape[0]].astype(np.float64)


def record_maniskill(folder: Path, env_id: str, *, name: str = "demos", episodes: int = 2, steps: int = 20,
                     **options: Any) -> Path:
    """Record `episodes` episodes of `steps` steps (seeds 0, 1, ...) with RecordEpisode into folder/name.h5.

    `options`: ``obs_mode`` (default "none", as published demos), ``control_mode`` (default "pd_joint_pos"),
    ``record_env_state`` / ``record_reward`` (default True), ``source_type``/``source_desc``.
    """
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401
    from mani_skill.utils.wrappers.record import RecordEpisode

    import simreel  # noqa: F401  (points SAPIEN at the software Vulkan driver on a CPU machine)

    env = gym.make(env_id, obs_mode=options.get("obs_mode", "none"),
                   control_mode=options.get("control_mode", "pd_joint_pos"))
    env = RecordEpisode(env, str(folder), trajectory_name=name, save_video=False,
                        record_env_state=options.get("record_env_state", True),
                        record_reward=options.get("record_reward", True),
                        source_type=options.get("source_type"), source_desc=options.get("source_desc"))
    space = env.action_space
    for k in range(episodes):
        env.reset(seed=k)
        for action in joint_targets(_start_targets(env), space.low, space.high, steps, seed=100 + k):
            env.step(action)
    env.close()
    return Path(folder) / f"{name}.h5"


def replay_maniskill(path: Path, env: dict[str, str], *args: str) -> Path:
    """Run ManiSkill's replay_trajectory on `path` with `args` (e.g. "-o", "state", "--use-env-states") and
    ``--save-traj``; return the file it wrote (``<stem>.<obs>.<control>.<backend>.h5`` beside `path`)."""
    before = set(Path(path).parent.glob("*.h5"))
    done = subprocess.run(
        [sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path", str(path), "--save-traj",
         "--allow-failure", *args],
        env=env, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    written = sorted(set(Path(path).parent.glob("*.h5")) - before)
    assert len(written) == 1, (written, done.stdout[-2000:])
    return written[0]
