"""Audit along real trajectories: restore-equivalence at every K-th step of recorded episodes or of a policy's.

A few random actions rarely reach the states where a task's hidden state matters: after a grasp, at success,
with a drawer half open. `audit_along` drives instance A of the task along real trajectories (the recorded
actions from each episode's reset, `simreel.sim.rebuild.reset_to_episode`, or a policy from ``reset(seed)``)
and, at every K-th step, resets instance B to another episode of the same scene, restores A's state into it
and compares what both compute (state dict, ``evaluate()`` info, observations, reward); then B follows A's
next action and their states are compared again. Each finding names the episode, the step and the phase the
trajectory was in (``grasped``, ``success``, ``cabinet moving``, ...), from A's own ``info`` and joints.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.model.components import Tolerances
from simreel.model.meta import EpisodeMeta
from simreel.model.state_tree import to_numpy
from simreel.replay.audit.checks import (
    DECLARE,
    AuditReport,
    Check,
    compare_computed,
    compare_states,
    computed_now,
    differing_attributes,
)
from simreel.sim.rebuild import GYM_MAKE_SEED, OTHER_EPISODE_OFFSET, another_episode, reset_to_episode
from simreel.sim.state import read_state, restore_state

__all__ = ["Trajectory", "recorded_trajectories", "policy_trajectories", "audit_along", "phase_of"]

_MOVING_QVEL = 1e-3
"""An articulation (not the robot) whose joint speed exceeds this (rad/s or m/s) is in a ``moving`` phase."""


@dataclass
class Trajectory:
    """One episode to audit along: how to reset to it, and its actions (recorded, or a policy asked step by step)."""

    label: str
    """``episode 3 of lift.h5`` or ``seed 0 with the scripted policy``."""
    episode: EpisodeMeta
    actions: Callable[[Any, Any, int], Any] | None = None
    """`(env, obs, t) -> action` (None: the trajectory ends)."""
    length: int = 0


def recorded_trajectories(path: str, indices: Iterable[int] | None = None) -> Iterator[Trajectory]:
    """The episodes of the recording at `path` (all, or `indices`: `RecordingFileError` for the first it lacks, before
    any is read), each with its recorded actions (read one episode at a time, without its observations: camera
    frames are never held)."""
    from simreel.formats import open_reader

    with open_reader(path) as reader:
        if indices is None:
            reader.refuse_damaged("audited along")
        for index in reader.named_episodes(indices) if indices is not None else [m.index for m in reader.episodes]:
            episode = reader.open_episode(index).episode(obs=False)
            actions = episode.actions

            def act(env: Any, obs: Any, t: int, actions: np.ndarray = actions) -> Any:
                import torch

                return torch.from_numpy(np.ascontiguousarray(actions[t : t + 1])) if t < len(actions) else None

            yield Trajectory(f"episode {index} of {path}", episode.meta, act, episode.length)


def policy_trajectories(policy: Callable[[Any, Any], Any], seeds: Iterable[int], max_steps: int,
                        name: str = "the policy") -> Iterator[Trajectory]:
    """One episode per seed, driven by `policy(env, obs) -> action` for up to `max_steps` steps (or until it ends)."""
    for k, seed in enumerate(seeds):
        episode = EpisodeMeta(index=k, seed=seed, reconfigured=True)  # the scene, too, from its seed
        yield Trajectory(f"seed {seed} with {name}", episode, lambda env, obs, t: policy(env, obs), max_steps)


def phase_of(unwrapped: Any, info: dict[str, Any]) -> str:
    """Where a trajectory is, in words, from the task's ``info`` and its non-robot joints: ``success``,
    ``grasped``, ``<articulation> moving`` (comma-separated), or ``not grasped``."""
    phases = []
    if "success" in info and bool(to_numpy(info["success"]).any()):
        phases.append("success")
    if any("grasp" in k and bool(to_numpy(v).any()) for k, v in info.items() if not isinstance(v, dict)):
        phases.append("grasped")
    agent = getattr(unwrapped, "agent", None)
    robot = getattr(getattr(agent, "robot", None), "name", None)
    for name, art in unwrapped.scene.state_dict_registry.articulations.items():
        if name != robot and art.max_dof and float(np.abs(to_numpy(art.qvel)).max(initial=0.0)) > _MOVING_QVEL:
            phases.append(f"{name} moving")
    return ", ".join(phases) or "not grasped"


class _AlongAuditor:
    """Drives A along one trajectory, restoring into B every `every` steps; adds findings to `report`."""

    def __init__(self, report: AuditReport, env_a: Any, env_b: Any, every: int) -> None:
        self.report, self.env_a, self.env_b, self.every = report, env_a, env_b, every
        self.scene_a: int | None = GYM_MAKE_SEED
        self.scene_b: int | None = GYM_MAKE_SEED
        self.tol_restore = Tolerances.for_mode("states")
        self.tol_step = Tolerances.for_mode("step")
        self.checked = 0

    def _reset_b(self, episode: EpisodeMeta) -> None:
        other = another_episode(episode)
        if other is None:  # the file does not say whether the reset rebuilt the scene: reset as given, another seed
            other = dataclasses.replace(episode, seed=(episode.seed or 0) + OTHER_EPISODE_OFFSET)
            note = ("the recording does not say whether its resets rebuilt the scene: the second instance is reset as "
                    "given with another seed (a task that rebuilds its scene at every reset would get another one)")
            if note not in self.report.notes:
                self.report.notes.append(note)
        self.scene_b = reset_to_episode(self.env_b, other, scene_seed=self.scene_b).scene_seed

    def _why(self, where: str, keys: list[str]) -> str:
        names = differing_attributes(self.env_a.unwrapped, self.env_b.unwrapped, keys)
        hint = f"; task attributes that still differ after the restore: {', '.join(names[:5])}" if names else ""
        return f"{where}: {DECLARE}{hint}"

    def run(self, traj: Trajectory) -> int:
        """Audit along `traj`; returns the number of steps driven."""
        ua = self.env_a.unwrapped
        self.scene_a = reset_to_episode(self.env_a, traj.episode, scene_seed=self.scene_a).scene_seed
        obs, following = ua.get_obs(), False
        for t in range(traj.length):
            action = traj.actions(self.env_a, obs, t)
            if action is None:
                return t
            before = _saved(ua)
            obs, reward, terminated, truncated, info = self.env_a.step(action)
            phase = f"{traj.label}, {phase_of(ua, info)}"
            if following:
                self.env_b.step(action)
                self._compare_step(t, phase)
            if t % self.every == self.every - 1 or t == 0:
                self._restore(traj.episode, t, phase, (before, action))
                following = True
            if bool(to_numpy(terminated).any() or to_numpy(truncated).any()):
                return t + 1
        return traj.length

    def _restore(self, episode: EpisodeMeta, t: int, phase: str, step: tuple[tuple[dict[str, np.ndarray], int], Any]) -> None:
        """B: another episode of the same scene, then A's state after step t; compare what both compute.

        Contact reports are not state: PhysX makes them when it steps, so right after a restore B would report the
        contacts of its own last step (and `is_grasping` with them). B therefore first takes step t's physics from
        A's state before it (the controller and the simulator only, none of the task's code, so no task state
        moves), then gets A's state after step t: its contacts are those of that step, like A's."""
        (before, elapsed_before), action = step
        ua, ub = self.env_a.unwrapped, self.env_b.unwrapped
        saved, elapsed = _saved(ua)
        self._reset_b(episode)
        restore_state(ub, before, elapsed_steps=elapsed_before)
        _physics_step(ub, action)
        restore_state(ub, saved, elapsed_steps=elapsed)
        why = "restoring the state dict into another instance does not reproduce it"
        compare_states(self.report, Check("restore_state", self.tol_restore, t, why, phase), saved,
                       {k: np.array(v) for k, v in read_state(ub).items()})
        batched = _batched(action, ua.device)
        why = self._why(f"after restoring the state after step {t} into another episode", list(saved))
        compare_computed(self.report, Check("restore", self.tol_restore, t, why, phase), computed_now(ua, batched),
                         computed_now(ub, batched))
        self.checked += 1

    def _compare_step(self, t: int, phase: str) -> None:
        """The state after both stepped from the restore: hidden state the physics uses. (What the task computes is
        compared at the restores; one step after a restore, velocities and contact flags carry PhysX's cache noise.)"""
        why = (f"after both stepped action {t} from the restored state: the state dict misses state that the physics "
               "or the task uses")
        compare_states(self.report, Check("step_state", self.tol_step, t, why, phase), read_state(self.env_a.unwrapped),
                       read_state(self.env_b.unwrapped))


def _saved(unwrapped: Any) -> tuple[dict[str, np.ndarray], int]:
    """The state dict now (copied) and the elapsed step count."""
    state = {k: np.array(v) for k, v in read_state(unwrapped).items()}
    return state, int(to_numpy(unwrapped._elapsed_steps).reshape(-1)[0])


def _physics_step(unwrapped: Any, action: Any) -> None:
    """One control step of the agent and the CPU simulator, without the task's step code (`BaseEnv._step_action`
    less its hooks): the contact reports it leaves are those of this step."""
    import torch

    u = unwrapped
    u.agent.set_action(torch.as_tensor(np.asarray(to_numpy(action)), device=u.device).reshape(1, -1))
    for _ in range(u._sim_steps_per_control):
        u.agent.before_simulation_step()
        u.scene.step()


def _batched(action: Any, device: Any) -> Any:
    import torch

    a = torch.as_tensor(np.asarray(to_numpy(action)), device=device)
    return a if a.ndim == 2 else a[None]


def audit_along(report: AuditReport, make: Callable[[], Any], trajectories: Iterator[Trajectory], *,
                every: int = 1) -> None:
    """Audit restore-equivalence along `trajectories` (see the module docstring), every `every` steps (and after the
    first); findings go to `report`, one line per trajectory to its checks."""
    env_a, env_b = make(), make()
    try:
        auditor = _AlongAuditor(report, env_a, env_b, every)
        for traj in trajectories:
            before = auditor.checked
            steps = auditor.run(traj)
            points = auditor.checked - before
            report.checks.append(f"restore-equivalence at {points} point{'s' * (points != 1)} along {traj.label} "
                                 f"({steps} steps, every {every})")
    finally:
        env_b.close()
        env_a.close()
