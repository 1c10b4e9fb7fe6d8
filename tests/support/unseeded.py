"""Recordings of unseeded episodes. `rl_rollout`: one seeded reset, then resets without a seed, as RL loops make
them; a replay remakes them from the recorded generator states. `record_unseeded`: unseeded episodes whose reset no
replay can remake, so it starts from their recorded initial state."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym

__all__ = ["DrawsAtReset", "record_unseeded", "rl_rollout"]


class DrawsAtReset(gym.Wrapper):
    """Draws from torch's global generator and from the task's episode generator before every reset of the env below
    it (as a user's own randomization might): a replay, which resets the task without this wrapper, cannot draw the
    same episode."""

    def reset(self, **kwargs):
        import torch

        torch.rand(3)
        self.env.unwrapped._episode_rng.rand(3)
        return self.env.reset(**kwargs)


def record_unseeded(env_id: str, path: Path, episodes: int = 1, *, preseed: int = 123, max_steps: int = 30) -> Path:
    """`episodes` episodes of a simreel lift task under its scripted policy, each reset without a seed.

    The env is reset once with `preseed` before recording (that reset is not recorded), and `DrawsAtReset` below the
    recorder draws from the generators the reset draws from, before it, so no replay can remake these resets: the replay
    restores the recorded initial state instead ("a restore-then-replay run"), and the task's own per-episode draws
    (the goal height) are the replaying env's.
    """
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env
    from simreel.tasks.policies import DEFAULT_POLICIES

    policy = DEFAULT_POLICIES[env_id]
    env = make_env(env_id, render_backend="none")
    env.reset(seed=preseed)
    rec = RecordWrapper(DrawsAtReset(env), path, overwrite=True)
    for _ in range(episodes):
        obs, _ = rec.reset()
        for _ in range(max_steps):
            obs, _, terminated, truncated, _ = rec.step(policy(rec, obs))
            if bool(terminated.any() or truncated.any()):
                break
    rec.close()
    return path


def rl_rollout(task: tuple[str, str], path: Path, *, shape: tuple[int, int] = (3, 15),
               reset_options: dict | None = None) -> Path:
    """An RL-style rollout of `task` (env id, control mode) recorded with `RecordWrapper`, `shape` (episodes, steps):
    one reset with seed 7, then `episodes` - 1 resets without one (with `reset_options`, e.g. a partial reset
    ``{"env_idx": [0]}``), `steps` random actions each, drawn from torch's global generator (as a policy samples
    them), which the unseeded resets draw from too."""
    import torch

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    (env_id, control_mode), (episodes, steps), seed = task, shape, 7
    env = make_env(env_id, render_backend="none", control_mode=control_mode)
    rec = RecordWrapper(env, path, overwrite=True, contacts="none")
    torch.manual_seed(seed)
    for e in range(episodes):
        rec.reset(seed=seed) if e == 0 else rec.reset(options=reset_options)
        for _ in range(steps):
            rec.step(torch.rand(rec.action_space.shape) * 2 - 1)
    rec.close()
    return path
