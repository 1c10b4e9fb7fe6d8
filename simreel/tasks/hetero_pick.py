"""SimreelHeteroPick-v1: pick up an object that differs per sub-scene (a merged, heterogeneous actor)."""

from __future__ import annotations

from typing import Any

import sapien
import sapien.physx as physx
import torch
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs.pose import Pose

from simreel.authoring.heterogeneous import build_heterogeneous_actor
from simreel.tasks._tabletop import HeterogeneousTabletopEnv
from simreel.tasks.shapes import add_object_shapes, sample_object

__all__ = ["HeteroPickEnv"]


@register_env("SimreelHeteroPick-v1", max_episode_steps=60)
class HeteroPickEnv(HeterogeneousTabletopEnv):
    """**Task:** grasp the object and lift it ``lift_height`` (8 cm) above its resting height.

    **Objects:** each sub-scene gets its own procedurally generated object (`simreel.tasks.shapes`): a
    box, an upright cylinder, a lying capsule or the convex hull of 24 random points; 3-9 cm long, at
    most 7 cm across the gripper, density 200-1200 kg/m³ (about 5-130 g). They are merged into one
    actor, ``self.obj``, registered as ``object``: the state dict has ``actors/object`` of shape
    (num_envs, 13) whatever was drawn.

    **Randomization:** the objects at reconfiguration (every reset when ``num_envs == 1``, as
    ``reconfiguration_freq`` defaults to 1 there; once otherwise), from the batched episode RNG, so the
    same seed gives the same object in sub-scene i on CPU and GPU and for any ``num_envs``. Per episode:
    object xy in [-0.1, 0.1]², yaw in [-0.3, 0.3] rad.

    **Success:** the object is grasped and lifted at least ``lift_height``.
    """

    simreel_contact_pairs = (
        "panda/panda_leftfinger:object",
        "panda/panda_rightfinger:object",
        "object:table-workspace",
    )
    lift_height = 0.08

    def _load_scene(self, options: dict):
        self._load_table()
        self.object_specs = [sample_object(self._batched_episode_rng[i]) for i in range(self.num_envs)]
        material = physx.PhysxMaterial(static_friction=1.0, dynamic_friction=1.0, restitution=0.0)

        def add_shapes(builder, i):
            add_object_shapes(builder, self.object_specs[i], material)
            builder.initial_pose = sapien.Pose(p=[0, 0, self.object_specs[i].rest_z])

        self.obj = build_heterogeneous_actor(self.scene, add_shapes, name="object")
        self.object_rest_z = torch.tensor([s.rest_z for s in self.object_specs], device=self.device)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            self.table_scene.initialize(env_idx)
            xyz = torch.zeros((len(env_idx), 3))
            xyz[:, :2] = self._uniform(env_idx, -0.1, 0.1, size=2)
            xyz[:, 2] = self.object_rest_z[env_idx]
            self.obj.set_pose(Pose.create_from_pq(xyz, self._yaw_quaternions(env_idx, -0.3, 0.3)))
            self.obj.set_linear_velocity(torch.zeros((len(env_idx), 3)))
            self.obj.set_angular_velocity(torch.zeros((len(env_idx), 3)))

    def evaluate(self):
        lifted_by = self.obj.pose.p[:, 2] - self.object_rest_z
        is_grasped = self.agent.is_grasping(self.obj)
        return {
            "success": is_grasped & (lifted_by >= self.lift_height),
            "is_grasped": is_grasped,
            "lifted_by": lifted_by,
        }

    def _get_obs_extra(self, info: dict):
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose, is_grasped=info["is_grasped"])
        if "state" in self.obs_mode:
            obs.update(
                obj_pose=self.obj.pose.raw_pose,
                tcp_to_obj_pos=self.obj.pose.p - self.agent.tcp.pose.p,
                lifted_by=info["lifted_by"][:, None],
            )
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        reward = 1 - torch.tanh(5 * self._tcp_to(self.obj.pose.p))
        is_grasped = info["is_grasped"].float()
        reward += is_grasped
        reward += torch.clamp(info["lifted_by"] / self.lift_height, 0, 1) * is_grasped
        reward[info["success"]] = 4
        return reward

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs=obs, action=action, info=info) / 4

    def object_kinds(self) -> list[str]:
        """The kind of object in each sub-scene (``box``, ``cylinder``, ``capsule`` or ``hull``)."""
        return [spec.kind for spec in self.object_specs]
