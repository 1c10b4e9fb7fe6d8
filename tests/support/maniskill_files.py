"""ManiSkill trajectory files made with ManiSkill's own tools, the way its users' datasets are made.

- `record_maniskill`: `mani_skill.utils.wrappers.RecordEpisode` around a plain ``gym.make`` env, driven in
  ``pd_joint_pos`` (the control mode of ManiSkill's published demos) along a path of joint targets: a random
  walk (``path="walk"``), a smooth path through random waypoints at the joint speeds of a motion-planned demo
  (``"smooth"``), or, for PickCube, a scripted grasp-and-lift planned with inverse kinematics (``"pick"``,
  what ManiSkill's motion-planning demos do), or a smooth swing of the arm alone, the robot's other controllers
  holding still (``"arm"``: for robots whose action is more than joint targets, as Fetch's with its mobile base);
  obs mode, env states and rewards as asked.
- `replay_maniskill`: `python -m mani_skill.trajectory.replay_trajectory` on such a file in a child process
  (it needs a render device: pass an environment with lavapipe), returning the file it wrote.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["record_maniskill", "replay_maniskill", "joint_targets", "smooth_targets", "pick_targets", "arm_targets"]

MAX_JOINT_STEP = 0.02
"""rad per step (0.4 rad/s at 20 Hz) of the smooth and planned paths: about the joint speed of ManiSkill's
motion-planned demos."""


def joint_targets(q0: np.ndarray, low: np.ndarray, high: np.ndarray, steps: int, seed: int) -> np.ndarray:
    """(steps, A) joint-position targets: from the robot's pose at reset, a smooth random walk within ±15% of
    each joint's range, inside the limits."""
    rng = np.random.default_rng(seed)
    span = (high - low).astype(np.float64)
    walk = np.cumsum(rng.normal(0.0, 0.02, (steps, len(q0))), axis=0)
    walk = np.clip(walk, -0.15, 0.15) * span
    return np.clip(q0 + walk, low, high).astype(np.float32)


def smooth_targets(q0: np.ndarray, low: np.ndarray, high: np.ndarray, steps: int, seed: int) -> np.ndarray:
    """(steps, A) joint-position targets: from the reset pose through random waypoints within ±15% of each
    joint's range, eased in and out between them, no joint faster than `MAX_JOINT_STEP`."""
    rng = np.random.default_rng(seed)
    span = (high - low).astype(np.float64)
    out, here = [], q0.astype(np.float64)
    while len(out) < steps:
        goal = np.clip(q0 + rng.uniform(-0.15, 0.15, len(q0)) * span, low, high)
        goal[-1] = here[-1]  # the gripper stays as it is
        out += list(_eased(here, goal))
        here = goal
    return np.asarray(out[:steps], np.float32)


def _eased(start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Joint targets from `start` to `goal` (excluded start, included goal) along a cosine ease, the fastest
    joint at `MAX_JOINT_STEP` per step at mid-way."""
    n = max(2, int(np.ceil(np.abs(goal - start).max() * np.pi / 2 / MAX_JOINT_STEP)))
    s = (1 - np.cos(np.linspace(0, np.pi, n + 1)[1:])) / 2
    return start + s[:, None] * (goal - start)


def pick_targets(env: Any, steps: int) -> np.ndarray:
    """(steps, 8) pd_joint_pos targets that pick PickCube's cube and carry it to the goal: joint paths between
    IK solutions (the robot's pinocchio model) above the cube, at it, (close), at the goal; then hold."""
    import sapien

    u = env.unwrapped
    robot = u.agent.robot
    model = robot.create_pinocchio_model()
    tcp = u.agent.tcp
    q = robot.get_qpos().cpu().numpy()[0].astype(np.float64)
    grasp = _grasp_pose(u.cube.pose.sp, tcp.pose.sp)
    root = robot.pose.sp
    plan, arm_dof = [], env.action_space.shape[0] - 1
    open_, closed = 1.0, -1.0
    for p, gripper in ((grasp.p + [0, 0, 0.08], open_), (grasp.p, open_), (grasp.p, closed),
                       (u.goal_site.pose.sp.p, closed)):
        goal_q, ok, _ = model.compute_inverse_kinematics(
            tcp.index.item(), root.inv() * sapien.Pose(p, grasp.q), initial_qpos=q, max_iterations=200)
        goal_q = goal_q if ok else q
        arm = _eased(q[:arm_dof], goal_q[:arm_dof]) if not np.allclose(goal_q, q) else np.repeat(q[None, :arm_dof], 6, 0)
        plan += [np.r_[a, gripper] for a in arm]
        q = goal_q
    plan += [plan[-1]] * max(0, steps - len(plan))
    return np.asarray(plan[:steps], np.float32)


def _grasp_pose(cube: Any, tcp: Any) -> Any:
    """The tcp pose that grasps `cube` from above: the tcp's own orientation turned about z to the cube's
    nearest face (a cube looks the same every 90 degrees)."""
    import sapien

    def heading(pose: Any) -> float:  # direction of the body's x axis in the world's xy plane
        x_axis = pose.to_transformation_matrix()[:3, 0]
        return float(np.arctan2(x_axis[1], x_axis[0]))

    yaw = (heading(cube) - heading(tcp) + np.pi / 4) % (np.pi / 2) - np.pi / 4
    turn = sapien.Pose(q=[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
    return sapien.Pose(cube.p, (turn * sapien.Pose(q=tcp.q)).q)


def _start_targets(env: Any) -> np.ndarray:
    """The joint targets that hold the robot where the reset put it (its qpos, one per action dimension)."""
    qpos = np.asarray(env.unwrapped.agent.robot.get_qpos())[0]
    return qpos[: env.action_space.shape[0]].astype(np.float64)


def record_maniskill(folder: Path, env_id: str, *, name: str = "demos", episodes: int = 2, steps: int = 20,
                     **options: Any) -> Path:
    """Record `episodes` episodes of `steps` steps (seeds 0, 1, ...) with RecordEpisode into folder/name.h5.

    `options`: ``obs_mode`` (default "none", as published demos), ``control_mode`` (default "pd_joint_pos"),
    ``record_env_state`` / ``record_reward`` / ``save_on_reset`` (default True; without the last, RecordEpisode writes
    an episode only at ``flush_trajectory()``, never called here), ``source_type``/``source_desc``, ``path``
    ("walk" default, "smooth" or "pick": see the module docstring), ``path_seed`` (of the first episode's path,
    default 100; episode k uses path_seed + k), ``env_kwargs``, ``seeded`` (default True; False: only the first
    episode resets with a seed, the others with none, as an RL loop does).
    """
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401
    from mani_skill.utils.wrappers.record import RecordEpisode

    from simreel.sim.make import prepare_plain_gym_make

    prepare_plain_gym_make()  # points SAPIEN at the software Vulkan driver on a CPU machine

    env = gym.make(env_id, obs_mode=options.get("obs_mode", "none"),
                   control_mode=options.get("control_mode", "pd_joint_pos"), **options.get("env_kwargs", {}))
    env = RecordEpisode(env, str(folder), trajectory_name=name, save_video=False,
                        record_env_state=options.get("record_env_state", True),
                        record_reward=options.get("record_reward", True),
                        save_on_reset=options.get("save_on_reset", True),
                        source_type=options.get("source_type"), source_desc=options.get("source_desc"))
    path = options.get("path", "walk")
    for k in range(episodes):
        env.reset(**({"seed": k} if k == 0 or options.get("seeded", True) else {}))
        for action in _path(env, path, steps, seed=options.get("path_seed", 100) + k):
            env.step(action)
    env.close()
    return Path(folder) / f"{name}.h5"


def arm_targets(env: Any, steps: int, seed: int) -> np.ndarray:
    """(steps, A) pd_joint_pos actions swinging the arm's joints smoothly by up to ±0.3 rad from their pose at reset
    and back (`MAX_JOINT_STEP` at most), the gripper at its reset position, every other controller at zero (a
    delta or a velocity: holding still)."""
    import torch

    controller = env.unwrapped.agent.controller
    rng = np.random.default_rng(seed)
    q0 = controller.controllers["arm"].qpos.cpu().numpy()[0].astype(np.float64)
    swing = rng.uniform(-0.3, 0.3, q0.shape) * min(1.0, MAX_JOINT_STEP * steps / (0.3 * np.pi))
    parts = {uid: torch.zeros((1, *c.action_space.shape)) for uid, c in controller.controllers.items()}
    if "gripper" in parts:
        parts["gripper"][:] = controller.controllers["gripper"].qpos[:, :1]
    out = []
    for t in range(steps):
        parts["arm"] = torch.as_tensor(q0 + swing * np.sin(np.pi * (t + 1) / steps), dtype=torch.float32)[None]
        out.append(controller.from_action_dict(parts).cpu().numpy()[0])
    return np.asarray(out, np.float32)


def _path(env: Any, path: str, steps: int, seed: int) -> np.ndarray:
    if path == "pick":
        return pick_targets(env, steps)
    if path == "arm":
        return arm_targets(env, steps, seed)
    space = env.action_space
    make = {"walk": joint_targets, "smooth": smooth_targets}[path]
    return make(_start_targets(env), space.low, space.high, steps, seed=seed)


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


def copy_recording(folder: Path, name: str, to: Path) -> Path:
    """folder/name.h5 and its sidecar copied into `to` (to alter them there); the copy's .h5 path."""
    for suffix in (".h5", ".json"):
        shutil.copy(folder / f"{name}{suffix}", to / f"{name}{suffix}")
    return to / f"{name}.h5"


def edit_sidecar(path: Path, change: Callable[[dict[str, Any]], Any]) -> None:
    """Apply `change` to the JSON sidecar of the ManiSkill file `path`, in place."""
    doc = json.loads(path.with_suffix(".json").read_text())
    change(doc)
    path.with_suffix(".json").write_text(json.dumps(doc))
