"""What the simreel example tasks share: a Panda at a table, end-effector control, batched-RNG sampling."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import sapien
import torch
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.scene_builder.table import TableSceneBuilder

from simreel.authoring.custom_state import CustomStateMixin

DEFAULT_CONTROL_MODE = "pd_ee_delta_pos"
"""Tasks default to end-effector position control; the scripted policies in `policies.py` need it."""


class TabletopPandaEnv(CustomStateMixin, BaseEnv):
    """A Panda at the origin-facing edge of ManiSkill's table; subclasses add objects and a goal.

    ``simreel_contact_pairs`` names the contacts a recorder should log with ``--contacts auto``, in
    simreel's pair syntax (``"<articulation>/<link>:<actor>"``, names as in the state-dict registry).
    """

    SUPPORTED_ROBOTS: ClassVar[list[str]] = ["panda"]
    simreel_contact_pairs: ClassVar[tuple[str, ...]] = ()

    def __init__(self, *args, robot_uids="panda", control_mode=None, robot_init_qpos_noise=0.02, **kwargs):
        self.robot_init_qpos_noise = robot_init_qpos_noise
        super().__init__(
            *args, robot_uids=robot_uids, control_mode=control_mode or DEFAULT_CONTROL_MODE, **kwargs
        )

    @property
    def _default_sensor_configs(self):
        pose = sapien_utils.look_at(eye=[0.3, 0, 0.6], target=[-0.1, 0, 0.1])
        return [CameraConfig("base_camera", pose, 128, 128, np.pi / 2, 0.01, 100)]

    @property
    def _default_human_render_camera_configs(self):
        pose = sapien_utils.look_at([0.6, 0.7, 0.6], [0.0, 0.0, 0.2])
        return CameraConfig("render_camera", pose, 512, 512, 1, 0.01, 100)

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=[-0.615, 0, 0]))

    def _load_table(self) -> None:
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=self.robot_init_qpos_noise)
        self.table_scene.build()

    def _uniform(self, env_idx: torch.Tensor, low, high, size=None) -> torch.Tensor:
        """Per-sub-scene uniform samples from the batched episode RNG: shape (len(env_idx), *size).

        Each sub-scene draws from its own seed, so the same seed gives the same episode on the CPU and
        the GPU sim and for any ``num_envs`` (torch.rand would not).
        """
        rng = self._batched_episode_rng[env_idx.cpu().numpy()]
        values = rng.uniform(low, high, size=size)
        return torch.as_tensor(values, dtype=torch.float32, device=self.device)

    def _yaw_quaternions(self, env_idx: torch.Tensor, low: float, high: float) -> torch.Tensor:
        """wxyz quaternions of a rotation about z by a per-sub-scene uniform angle: (len(env_idx), 4)."""
        half = self._uniform(env_idx, low, high) / 2
        zeros = torch.zeros_like(half)
        return torch.stack([torch.cos(half), zeros, zeros, torch.sin(half)], dim=1)

    def _tcp_to(self, target: torch.Tensor) -> torch.Tensor:
        return torch.linalg.norm(target - self.agent.tcp.pose.p, dim=1)


class HeterogeneousTabletopEnv(TabletopPandaEnv):
    """A tabletop task whose sub-scenes hold different objects.

    With one env (the CPU sim) the scene is rebuilt at every reset by default, so the object varies
    across episodes; with many envs (the GPU sim) it varies across sub-scenes. Merged objects with many
    shapes need more GPU contact buffers than ManiSkill's defaults.
    """

    def __init__(self, *args, num_envs=1, reconfiguration_freq=None, **kwargs):
        if reconfiguration_freq is None:
            reconfiguration_freq = 1 if num_envs == 1 else 0
        super().__init__(*args, num_envs=num_envs, reconfiguration_freq=reconfiguration_freq, **kwargs)

    @property
    def _default_sim_config(self):
        from mani_skill.utils.structs.types import GPUMemoryConfig, SimConfig

        return SimConfig(
            gpu_memory_config=GPUMemoryConfig(max_rigid_contact_count=2**20, max_rigid_patch_count=2**19)
        )
