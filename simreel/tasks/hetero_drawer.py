"""SimreelHeteroDrawer-v1: open a drawer of a cabinet that differs per sub-scene (merged articulations)."""

from __future__ import annotations

from typing import Any

import sapien
import sapien.physx as physx
import torch
from mani_skill.utils.registration import register_env

from simreel.authoring.heterogeneous import build_heterogeneous_articulation
from simreel.tasks._tabletop import HeterogeneousTabletopEnv
from simreel.tasks.cabinets import MAX_DOF, add_cabinet_links, sample_cabinet

__all__ = ["HeteroDrawerEnv"]


@register_env("SimreelHeteroDrawer-v1", max_episode_steps=80)
class HeteroDrawerEnv(HeterogeneousTabletopEnv):
    """**Task:** grasp the handle of the target drawer and pull the drawer ``open_distance`` (10 cm) out.

    **Cabinets:** each sub-scene gets its own procedurally built cabinet with 1-3 joints: prismatic
    drawers side by side and revolute knobs on top (see `simreel.tasks.cabinets`). They are merged into
    one articulation ``cabinet`` whose state is padded to 3 DOF: ``articulations/cabinet`` has shape
    (num_envs, 19) whatever was drawn. The target drawer's link of every sub-scene is merged into
    ``handle`` (``cabinet.links_map["handle"]``), so ``self.handle.joint.qpos`` is the opening of the
    target drawer in each sub-scene, shape (num_envs,).

    **Randomization:** cabinets at reconfiguration (every reset when ``num_envs == 1``; once otherwise),
    from the batched episode RNG; per episode only the robot's initial joint noise. All joints closed.

    **Success:** the target drawer is open at least ``open_distance``.
    """

    simreel_contact_pairs = (
        "panda/panda_leftfinger:cabinet/handle",
        "panda/panda_rightfinger:cabinet/handle",
    )
    open_distance = 0.1

    def _load_scene(self, options: dict):
        self._load_table()
        self.cabinet_specs = [sample_cabinet(self._batched_episode_rng[i]) for i in range(self.num_envs)]
        grip = physx.PhysxMaterial(static_friction=1.5, dynamic_friction=1.5, restitution=0.0)

        def add_links(builder, i):
            spec = self.cabinet_specs[i]
            add_cabinet_links(builder, spec, grip)
            builder.initial_pose = sapien.Pose(p=[spec.front_x, 0, 0])

        self.cabinet = build_heterogeneous_articulation(
            self.scene, add_links, name="cabinet", state_dof=MAX_DOF, merged_links=["handle"]
        )
        self.handle = self.cabinet.links_map["handle"]

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            self.table_scene.initialize(env_idx)
            n = len(env_idx)
            self.cabinet.set_qpos(torch.zeros((n, self.cabinet.max_dof)))
            self.cabinet.set_qvel(torch.zeros((n, self.cabinet.max_dof)))

    def evaluate(self):
        opened = self.handle.joint.qpos
        is_grasped = self.agent.is_grasping(self.handle)
        return {
            "success": opened >= self.open_distance,
            "is_grasped": is_grasped,
            "opened": opened,
        }

    def _get_obs_extra(self, info: dict):
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose, is_grasped=info["is_grasped"])
        if "state" in self.obs_mode:
            obs.update(
                handle_pos=self.handle.pose.p,
                tcp_to_handle_pos=self.handle.pose.p - self.agent.tcp.pose.p,
                opened=info["opened"][:, None],
            )
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        reward = 1 - torch.tanh(5 * self._tcp_to(self.handle.pose.p))
        is_grasped = info["is_grasped"].float()
        reward += is_grasped
        reward += torch.clamp(info["opened"] / self.open_distance, 0, 1) * 2
        reward[info["success"]] = 5
        return reward

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs=obs, action=action, info=info) / 5

    def cabinet_dofs(self) -> list[int]:
        """The number of joints of the cabinet in each sub-scene."""
        return [spec.dof for spec in self.cabinet_specs]
