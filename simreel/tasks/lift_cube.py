"""SimreelLiftCube-v1: lift a cube to a target height sampled per episode (custom state).

The target height exists only in the task, not in the physics, so it is declared custom state and
travels in the state dict as ``state["goal_height"]`` (shape ``(num_envs,)``). The leaky variant
SimreelLiftCubeLeaky-v1 is the same task without that declaration: a restored state then keeps
whatever height the env had, which `simreel audit` must report. SimreelLiftCubeStageLeaky-v1 leaks state
that matters only after the cube is lifted, which an audit finds only along a real trajectory.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import sapien
import torch
from mani_skill.utils.building import actors
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs.pose import Pose

from simreel.tasks._tabletop import TabletopPandaEnv

__all__ = ["LiftCubeEnv", "LiftCubeLeakyEnv", "LiftCubeStageLeakyEnv"]


@register_env("SimreelLiftCube-v1", max_episode_steps=60)
class LiftCubeEnv(TabletopPandaEnv):
    """**Task:** grasp a 4 cm cube and hold it with its centre at a target height.

    **Randomization (per episode, from the batched episode RNG):** cube xy in [-0.1, 0.1]², yaw;
    target height of the cube centre in [0.08, 0.25] m.

    **Success:** the cube is grasped and its centre is within 2 cm of the target height.

    **Custom state:** ``goal_height`` (num_envs,), in the state dict and in the observation.

    **Kwargs:** ``cube_mass`` (kg; default from the cube's density: 0.064).
    """

    custom_state = ("goal_height",)
    simreel_contact_pairs = (
        "panda/panda_leftfinger:cube",
        "panda/panda_rightfinger:cube",
        "cube:table-workspace",
    )
    cube_half_size = 0.02
    cube_mass: float | None = None
    """The cube's mass in kg (None: from its density, 0.064 kg); the ``cube_mass`` kwarg sets it, as domain
    randomization of a physical property would."""
    goal_height_range = (0.08, 0.25)
    goal_thresh = 0.02

    def __init__(self, *args, cube_mass: float | None = None, **kwargs):
        if cube_mass is not None:
            self.cube_mass = float(cube_mass)
        super().__init__(*args, **kwargs)

    def _load_scene(self, options: dict):
        self._load_table()
        self.cube = actors.build_cube(
            self.scene,
            half_size=self.cube_half_size,
            color=[1, 0, 0, 1],
            name="cube",
            initial_pose=sapien.Pose(p=[0, 0, self.cube_half_size]),
        )
        if self.cube_mass is not None:
            for body in self.cube._bodies:
                scale = self.cube_mass / body.mass
                body.mass, body.inertia = self.cube_mass, body.inertia * scale
        self.goal_height = torch.zeros(self.num_envs, device=self.device)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            self.table_scene.initialize(env_idx)
            xyz = torch.zeros((len(env_idx), 3))
            xyz[:, :2] = self._uniform(env_idx, -0.1, 0.1, size=2)
            xyz[:, 2] = self.cube_half_size
            self.cube.set_pose(Pose.create_from_pq(xyz, self._yaw_quaternions(env_idx, -np.pi, np.pi)))
            self.goal_height[env_idx] = self._uniform(env_idx, *self.goal_height_range)

    def evaluate(self):
        height_error = self.goal_height - self.cube.pose.p[:, 2]
        is_grasped = self.agent.is_grasping(self.cube)
        at_height = height_error.abs() <= self.goal_thresh
        return {
            "success": is_grasped & at_height,
            "is_grasped": is_grasped,
            "at_height": at_height,
            "height_error": height_error,
        }

    def _get_obs_extra(self, info: dict):
        obs = dict(
            tcp_pose=self.agent.tcp.pose.raw_pose,
            goal_height=self.goal_height[:, None],
            is_grasped=info["is_grasped"],
        )
        if "state" in self.obs_mode:
            obs.update(
                obj_pose=self.cube.pose.raw_pose,
                tcp_to_obj_pos=self.cube.pose.p - self.agent.tcp.pose.p,
                obj_to_goal_height=info["height_error"][:, None],
            )
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        reward = 1 - torch.tanh(5 * self._tcp_to(self.cube.pose.p))
        is_grasped = info["is_grasped"].float()
        reward += is_grasped
        reward += (1 - torch.tanh(5 * info["height_error"].abs())) * is_grasped
        reward[info["success"]] = 4
        return reward

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs=obs, action=action, info=info) / 4


@register_env("SimreelLiftCubeLeaky-v1", max_episode_steps=60)
class LiftCubeLeakyEnv(LiftCubeEnv):
    """SimreelLiftCube-v1 with a deliberate bug: ``goal_height`` is a plain attribute, not custom state.

    Recording and replaying actions still work; restoring a state does not restore the height, so
    success and reward after `set_state_dict` follow the env's current episode, not the recorded one.
    It exists so that tests can prove `simreel audit` catches state that lives outside the state dict.
    """

    custom_state = ()


@register_env("SimreelLiftCubeStageLeaky-v1", max_episode_steps=60)
class LiftCubeStageLeakyEnv(LiftCubeEnv):
    """SimreelLiftCube-v1 with a staged success and a deliberate bug that only shows mid-task.

    The task latches a stage, ``lifted``, once the cube has risen ``lift_threshold`` above its resting height,
    and keeps it until the episode ends; success needs it. The latch is a plain attribute, not custom state,
    so the state dict leaves it out, but until the cube is lifted it is ``False`` in every instance and a
    restore loses nothing. Only after the lift does a restored state (into an env that never lifted) report
    another success and reward. An audit driven by a few random actions never lifts the cube and misses the
    leak; ``simreel audit SimreelLiftCubeStageLeaky-v1 --policy scripted`` (along the scripted policy's
    trajectory) names the step where it shows.
    """

    lift_threshold = 0.03

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        self.lifted = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        super()._initialize_episode(env_idx, options)
        self.lifted[env_idx] = False

    def _step_action(self, action):
        action = super()._step_action(action)  # the physics has stepped (and, on the GPU, been fetched)
        self.lifted |= self.cube.pose.p[:, 2] >= self.cube_half_size + self.lift_threshold
        return action

    def evaluate(self):
        info = super().evaluate()
        info["lifted"] = self.lifted.clone()
        info["success"] = info["success"] & self.lifted
        return info
