"""Recordings of unseeded episodes: a replay cannot reset to them, so it starts from their recorded initial state."""

from __future__ import annotations

from pathlib import Path

__all__ = ["record_unseeded"]


def record_unseeded(env_id: str, path: Path, episodes: int = 1, *, preseed: int = 123, max_steps: int = 30) -> Path:
    """`episodes` episodes of a simreel lift task under its scripted policy, each reset without a seed.

    The env is reset once with `preseed` before recording (that reset is not recorded), so the unseeded resets draw
    their episodes from the RNG that seed set: deterministic here, and out of reach of a replay, whose env never
    resets with it. The replay restores the recorded initial state instead ("a restore-then-replay run"), and the
    task's own per-episode draws (the goal height) are the replaying env's.
    """
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env
    from simreel.tasks.policies import DEFAULT_POLICIES

    policy = DEFAULT_POLICIES[env_id]
    env = make_env(env_id, render_backend="none")
    env.reset(seed=preseed)
    rec = RecordWrapper(env, path, overwrite=True)
    for _ in range(episodes):
        obs, _ = rec.reset()
        for _ in range(max_steps):
            obs, _, terminated, truncated, _ = rec.step(policy(rec, obs))
            if bool(terminated.any() or truncated.any()):
                break
    rec.close()
    return path
