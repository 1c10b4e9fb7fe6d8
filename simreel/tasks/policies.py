"""Scripted policies for simreel's example tasks: plain callables ``policy(env, obs) -> action``.

``env`` is the gym env as the user holds it (wrapped or not); the policies read poses from
``env.unwrapped`` and return a torch tensor of shape ``(num_envs, 4)`` for the ``pd_ee_delta_pos``
control mode the tasks default to (3 end-effector deltas in [-1, 1] scaled to ±0.1 m, then the gripper:
1 open, -1 closed). They are stateless proportional controllers (no motion planner): each step decides
from the current poses whether to hover over the object, descend, close, or carry, so they work per
sub-scene on batched envs and after any state restore. Use them from the CLI as
``--policy simreel.tasks.policies:lift_cube_policy``.
"""

from __future__ import annotations

from typing import Any

import torch

__all__ = [
    "DEFAULT_POLICIES",
    "hetero_drawer_policy",
    "hetero_pick_policy",
    "lift_cube_policy",
]

_GAIN = 10.0  # normalized action per metre of error: 10 cm error -> full speed (0.1 m per step)
_HOVER = 0.08  # approach height above the grasp point
_XY_TOL = 0.012  # descend only when the tcp is this close (xy) to the grasp point
_Z_TOL = 0.012  # close the gripper when the tcp is this close (z) to the grasp point
OPEN, CLOSED = 1.0, -1.0


def _check_mode(base: Any) -> None:
    if base.control_mode != "pd_ee_delta_pos":
        from simreel.errors import UsageError

        raise UsageError(
            f"the scripted policies drive control mode 'pd_ee_delta_pos', the env uses {base.control_mode!r}; "
            f"make the env with control_mode='pd_ee_delta_pos' (the default of simreel's tasks)"
        )


def _action(tcp: torch.Tensor, target: torch.Tensor, gripper: torch.Tensor, max_step: float = 1.0):
    delta = torch.clamp(_GAIN * (target - tcp), -max_step, max_step)
    return torch.cat([delta, gripper[:, None]], dim=1)


def _reach_and_grasp(tcp: torch.Tensor, grasp_point: torch.Tensor, grasped: torch.Tensor):
    """Target and gripper command of the approach phase: hover over the grasp point, descend, close.

    Returns (target, gripper, near) where ``near`` marks sub-scenes whose tcp is at the grasp point.
    """
    xy_err = torch.linalg.norm(tcp[:, :2] - grasp_point[:, :2], dim=1)
    z_err = (tcp[:, 2] - grasp_point[:, 2]).abs()
    aligned = xy_err <= _XY_TOL
    target = grasp_point.clone()
    # not above the object yet: go to hover height first (never dive sideways into it)
    target[:, 2] = torch.where(aligned, grasp_point[:, 2], grasp_point[:, 2] + _HOVER)
    high_enough = tcp[:, 2] >= grasp_point[:, 2] + _HOVER / 2
    target[:, :2] = torch.where((aligned | high_enough)[:, None], grasp_point[:, :2], tcp[:, :2])
    near = aligned & (z_err <= _Z_TOL)
    gripper = torch.full_like(tcp[:, 0], OPEN).masked_fill(near | grasped, CLOSED)
    return target, gripper, near


def lift_cube_policy(env: Any, obs: Any = None) -> torch.Tensor:
    """SimreelLiftCube-v1 and its leaky variants: grasp the cube, carry it to ``goal_height``."""
    base = env.unwrapped
    _check_mode(base)
    tcp, cube = base.agent.tcp.pose.p, base.cube.pose.p
    grasped = base.agent.is_grasping(base.cube)
    target, gripper, _ = _reach_and_grasp(tcp, cube, grasped)
    lift = tcp.clone()
    lift[:, 2] += base.goal_height - cube[:, 2]
    target = torch.where(grasped[:, None], lift, target)
    return _action(tcp, target, gripper)


def hetero_pick_policy(env: Any, obs: Any = None) -> torch.Tensor:
    """SimreelHeteroPick-v1: grasp the object at its centre and lift it by ``lift_height``."""
    base = env.unwrapped
    _check_mode(base)
    tcp, obj = base.agent.tcp.pose.p, base.obj.pose.p
    grasped = base.agent.is_grasping(base.obj)
    target, gripper, _ = _reach_and_grasp(tcp, obj, grasped)
    lift = tcp.clone()
    lift[:, 2] += base.object_rest_z + base.lift_height + 0.02 - obj[:, 2]
    target = torch.where(grasped[:, None], lift, target)
    return _action(tcp, target, gripper)


def hetero_drawer_policy(env: Any, obs: Any = None) -> torch.Tensor:
    """SimreelHeteroDrawer-v1: grasp the handle from above and pull it along -x until open."""
    base = env.unwrapped
    _check_mode(base)
    tcp, handle = base.agent.tcp.pose.p, base.handle.pose.p
    grasped = base.agent.is_grasping(base.handle)
    target, gripper, near = _reach_and_grasp(tcp, handle, grasped)
    pull = tcp.clone()
    pull[:, 0] -= 0.03
    target = torch.where((grasped | (near & (base.handle.joint.qpos > 0.005)))[:, None], pull, target)
    return _action(tcp, target, gripper)


DEFAULT_POLICIES = {
    "SimreelLiftCube-v1": lift_cube_policy,
    "SimreelLiftCubeLeaky-v1": lift_cube_policy,
    "SimreelLiftCubeStageLeaky-v1": lift_cube_policy,
    "SimreelHeteroPick-v1": hetero_pick_policy,
    "SimreelHeteroDrawer-v1": hetero_drawer_policy,
}
"""The scripted policy of each task id (what the CLI uses when ``--policy`` is not given)."""
