"""Control-mode conversion: turn each recorded action into the action of another control mode, one step for one.

A converter is bound to the live env that replays the converted actions (`bind`, after every reset: a reset
may rebuild the scene and its controllers) and, for each recorded action, returns the target mode's action
computed from where the robot is now, closed-loop, as ManiSkill's own converters do
(`mani_skill.trajectory.utils.actions.conversion`, whose per-step formulas are reused here):

    pd_joint_pos        -> pd_joint_delta_pos     delta = recorded joint target - current qpos, normalized
    pd_joint_pos        -> pd_joint_target_delta_pos    delta = recorded joint target - the controller's kept
                                                  joint target, normalized
    pd_joint_pos        -> pd_joint_vel           velocity = (recorded joint target - current qpos) x control rate
    pd_joint_pos        -> pd_ee_delta_pos/pose   the end-effector pose of the recorded joint target (forward
                                                  kinematics), as a delta from the current end-effector pose
    pd_joint_pos        -> pd_ee_target_delta_pos/pose    the same pose, as a delta from the controller's kept
                                                  end-effector target
    pd_joint_delta_pos  -> pd_joint_pos           current qpos + the recorded delta

The target modes keep a target that each action moves (it accumulates, a clipped step included): their converters
read it from the live controller before each step, so the next action makes up what a clipped one left out. A reset
sets it to where the robot is; `bind` does so again (after a restored initial state the controller's target is
still the reset's: ManiSkill's ``set_state_dict`` does not restore controllers).

Unlike ManiSkill's converters, one recorded step gives exactly one converted step: where the target mode's
action limits cannot reach the recorded target in one step, the action is clipped (as ManiSkill clips it)
and the step is marked, instead of stepping again (ManiSkill inserts up to 1 or 3 extra steps there, which
changes the episode's length and timing). Whether the converted trajectory is still the same one is then
measured step by step (`simreel.replay.convert.tracking`). Controllers other than the arm (the gripper) must be the
same in both modes; their actions are copied.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from simreel.errors import UsageError

__all__ = ["SUPPORTED", "ActionConverter", "ConvertedAction", "check_pair", "converter_for"]

SUPPORTED: dict[str, tuple[str, ...]] = {
    "pd_joint_pos": ("pd_joint_delta_pos", "pd_joint_target_delta_pos", "pd_joint_vel", "pd_ee_delta_pos",
                     "pd_ee_delta_pose", "pd_ee_target_delta_pos", "pd_ee_target_delta_pose"),
    "pd_joint_delta_pos": ("pd_joint_pos",),
}
"""Source control mode -> the target modes simreel converts it to."""

_CLIP_SLACK = 1e-3
"""A normalized action beyond 1 + this counts as clipped (ManiSkill's own threshold)."""


@dataclass(frozen=True)
class ConvertedAction:
    """One converted action, whether the target mode's limits clipped it, and the tool-centre pose the recorded
    action commanded (``[x y z qw qx qy qz]``, world frame; None where there is no tool-centre link): the
    converted command is checked against it (`ActionConverter.commanded`)."""

    action: np.ndarray
    clipped: bool
    wanted: np.ndarray | None = None


class ActionConverter(Protocol):
    """Converts recorded actions into a target control mode on a live env (see the module docstring)."""

    target_mode: str

    def bind(self, unwrapped: Any) -> None:
        """Use the controllers of `unwrapped` (the env that steps the converted actions) from now on."""

    def __call__(self, action: np.ndarray) -> ConvertedAction:
        """The target mode's action for recorded action `action`, given the env's current state."""

    def commanded(self) -> np.ndarray | None:
        """After the converted action was stepped: the tool-centre pose it commanded (None: not known). Optional
        for converters of one's own: without it, the commands are not compared (the trajectory still is)."""


def check_pair(source: str | None, target: str) -> None:
    """`UsageError` unless simreel converts control mode `source` to `target` (no env needed)."""
    if source == target:
        raise UsageError(f"--control-mode {target} is the recording's own control mode: nothing to convert")
    targets = SUPPORTED.get(source or "")
    if targets is None or target not in targets:
        pairs = "; ".join(f"{s} -> {', '.join(t)}" for s, t in SUPPORTED.items())
        raise UsageError(f"cannot convert control mode {source} to {target}: simreel converts {pairs}")


def converter_for(source: str, target: str, unwrapped: Any, source_controller: Any) -> ActionConverter:
    """The converter of `source` -> `target` for the robot of `unwrapped` (built in the target mode);
    `source_controller` is the robot's controller in the source mode (it splits recorded actions).

    Raises `UsageError` for a pair or robot it cannot convert: no ``arm`` controller of the expected kind, other
    controllers that differ between the two modes, no tool-centre link to track.
    """
    check_pair(source, target)
    _check_controllers(unwrapped, source_controller, unwrapped.agent.controller, (source, target))
    if target.startswith("pd_ee_"):
        return EePoseFromJointPos(target, source_controller)
    if source == "pd_joint_pos":
        return JointFromJointPos(target, source_controller)
    return JointPosFromJointDelta(target, source_controller)


def _env_id(unwrapped: Any) -> str:
    spec = getattr(unwrapped, "spec", None)
    return spec.id if spec is not None else type(unwrapped).__name__


def _check_controllers(unwrapped: Any, source: Any, target: Any, modes: tuple[str, str]) -> None:
    """Both modes drive an ``arm`` of the kind the pair needs and the same other controllers (copied as
    recorded); an end-effector target needs a tool-centre link."""
    robot = f"{_env_id(unwrapped)}: robot {getattr(unwrapped.agent, 'uid', '?')}"
    parts, now = getattr(source, "controllers", None), getattr(target, "controllers", None)
    if not isinstance(parts, dict) or not isinstance(now, dict) or "arm" not in parts or "arm" not in now:
        raise UsageError(f"{robot} has no 'arm' controller in {modes[0]} and {modes[1]}; control-mode conversion "
                         "needs an arm driven by joint-position or end-effector controllers (ManiSkill's converters "
                         "are written for the Panda arm)")
    for mode, arm in zip(modes, (parts["arm"], now["arm"]), strict=True):
        if not _arm_fits(mode, arm.config):
            raise UsageError(f"{robot}'s arm controller in {mode} ({type(arm).__name__}: use_delta "
                             f"{getattr(arm.config, 'use_delta', '?')}, use_target {getattr(arm.config, 'use_target', '?')}) "
                             "is not the kind simreel converts")
    differ = sorted(uid for uid in set(parts) | set(now) if uid != "arm"
                    and (uid not in parts or uid not in now or repr(parts[uid].config) != repr(now[uid].config)))
    if differ:
        raise UsageError(f"{robot}'s {', '.join(differ)} controllers differ between {modes[0]} and {modes[1]}: "
                         "their recorded actions cannot be copied")
    tcp = getattr(unwrapped.agent, "tcp", None)
    if modes[1].startswith("pd_ee_") and tcp is None:
        raise UsageError(f"{robot} has no tool-centre link (agent.tcp) to convert to {modes[1]}")
    ee_link = getattr(now["arm"], "ee_link", None)
    if modes[1].startswith("pd_ee_") and getattr(ee_link, "name", None) != tcp.name:
        raise UsageError(f"{robot}'s {modes[1]} controller moves link {getattr(ee_link, 'name', '?')}, not the "
                         f"tool-centre link {tcp.name} the conversion tracks")


def _arm_fits(mode: str, config: Any) -> bool:
    """Whether an arm controller config is what `mode`'s converter computes for: joint positions, normalized joint
    velocities, normalized joint deltas from the current positions; end-effector deltas in the root frame, from the
    current pose, or from the kept target in the modes named ``*_target_*``."""
    use_delta, use_target = getattr(config, "use_delta", None), bool(getattr(config, "use_target", None))
    normalized = getattr(config, "normalize_action", None)
    keeps_target = "_target_" in mode
    if mode.startswith("pd_ee_"):
        frame = str(getattr(config, "frame", ""))
        return bool(use_delta and use_target == keeps_target and normalized and frame.startswith("root_translation"))
    if not hasattr(config, "lower") or hasattr(config, "frame"):
        return False
    if mode == "pd_joint_vel":
        return use_delta is None and bool(normalized)
    if mode == "pd_joint_pos":
        return use_delta is False
    return bool(use_delta and use_target == keeps_target and normalized)


def _clip(action: np.ndarray) -> tuple[np.ndarray, bool]:
    clipped = bool(np.abs(action).max(initial=0.0) > 1 + _CLIP_SLACK)
    return np.clip(action, -1.0, 1.0), clipped


class _Converter:
    """What every converter shares: the source controller that splits recorded actions, the live target
    controller that joins converted parts, and the robot's kinematics for the tool-centre pose of a command."""

    def __init__(self, target_mode: str, source_controller: Any) -> None:
        self.target_mode = target_mode
        self.source = source_controller
        self.controller: Any = None
        self.arm: Any = None

    def bind(self, unwrapped: Any) -> None:
        self.controller = unwrapped.agent.controller
        self.arm = self.controller.controllers["arm"]
        self.robot = unwrapped.agent.robot
        self.tcp = getattr(unwrapped.agent, "tcp", None)
        self.model = self.robot.create_pinocchio_model()
        self.arm_joints = self.arm.active_joint_indices.cpu().numpy()
        self.fk_qpos: np.ndarray | None = None
        """The robot's joint positions of the last tool pose computed (`_tool_pose`): the command check's."""
        self.root_at_action: Any = None
        """Where the end-effector controller's root link was when the last action was made (its target's frame)."""
        if getattr(self.arm.config, "use_target", False):
            self._reset_target()

    def _reset_target(self) -> None:
        """Set the arm's kept target to where the robot is, as a reset does."""
        if hasattr(self.arm.config, "frame"):
            self.arm._target_pose = self.arm.ee_pose_at_base
        else:
            self.arm._target_qpos = self.arm.qpos.clone()

    def _join(self, parts: dict[str, np.ndarray], arm: np.ndarray) -> np.ndarray:
        import torch

        joined = {uid: torch.as_tensor(np.asarray(a, np.float32)) for uid, a in parts.items()}
        joined["arm"] = torch.as_tensor(np.asarray(arm, np.float32))
        return self.controller.from_action_dict(joined).numpy().astype(np.float32)

    def _qpos(self) -> np.ndarray:
        return self.arm.qpos.cpu().numpy()[0].astype(np.float64)

    def _tool_pose(self, arm_target: np.ndarray, robot_qpos: np.ndarray | None = None) -> Any:
        """The world pose (sapien.Pose) of the tool-centre link with the arm's joints at `arm_target`, the robot's
        other joints at `robot_qpos` (None: where they are now; kept in `fk_qpos` for the command check)."""
        qpos = self.robot.get_qpos().cpu().numpy()[0].astype(np.float64) if robot_qpos is None else robot_qpos.copy()
        self.fk_qpos = qpos.copy()
        qpos[self.arm_joints] = arm_target
        self.model.compute_forward_kinematics(qpos)
        return self.robot.pose.sp * self.model.get_link_pose(int(self.tcp.index.item()))

    def _wanted(self, arm_target: np.ndarray) -> np.ndarray | None:
        if self.tcp is None:
            return None
        pose = self._tool_pose(arm_target)
        return np.r_[pose.p, pose.q]

    def commanded(self) -> np.ndarray | None:
        """The tool-centre pose ``[x y z qw qx qy qz]`` the arm controller was last commanded to reach: its target
        pose (end-effector controllers), else the pose of its joint target; None without a tool-centre link."""
        if self.tcp is None:
            return None
        target = getattr(self.arm, "_target_pose", None)
        joints = getattr(self.arm, "_target_qpos", None)  # none for a velocity controller: no pose commanded
        if target is not None and hasattr(self.arm.config, "frame"):
            root = self.arm.root_link.pose.sp if self.root_at_action is None else self.root_at_action
            pose = root * target.sp  # the target in the frame the action was made in
        elif joints is not None:  # the robot's other joints (a torso, a mobile base) where the wanted pose had them
            pose = self._tool_pose(joints.cpu().numpy()[0], self.fk_qpos)
        else:
            return None
        return np.r_[pose.p, pose.q]


class JointFromJointPos(_Converter):
    """pd_joint_pos -> pd_joint_delta_pos, pd_joint_target_delta_pos or pd_joint_vel: ManiSkill's formula of the
    target mode (the recorded joint target minus the current joint positions or the controller's kept target, or the
    first difference times the control rate), normalized and clipped."""

    def __call__(self, action: np.ndarray) -> ConvertedAction:
        from mani_skill.trajectory.utils.actions import conversion

        formula = {"pd_joint_delta_pos": conversion.qpos_to_pd_joint_delta_pos,
                   "pd_joint_target_delta_pos": conversion.qpos_to_pd_joint_target_delta_pos,
                   "pd_joint_vel": conversion.qpos_to_pd_joint_vel}[self.target_mode]
        parts = self.source.to_action_dict(np.asarray(action))
        arm, clipped = _clip(np.asarray(formula(self.arm, parts["arm"]), np.float64))
        return ConvertedAction(self._join(parts, arm), clipped, self._wanted(parts["arm"]))


class JointPosFromJointDelta(_Converter):
    """pd_joint_delta_pos -> pd_joint_pos: the current joint positions plus the recorded (scaled) delta. (The
    command it checks is that target itself: the recorded run's own target needs its joint positions at the step,
    which the tracking of states compares instead.)"""

    def __call__(self, action: np.ndarray) -> ConvertedAction:
        cfg = self.source.controllers["arm"].config
        parts = self.source.to_action_dict(np.asarray(action))
        delta = np.clip(parts["arm"], -1.0, 1.0)
        low, high = np.asarray(cfg.lower, np.float64), np.asarray(cfg.upper, np.float64)
        target = self._qpos() + 0.5 * (high + low) + 0.5 * (high - low) * delta
        return ConvertedAction(self._join(parts, target), False, self._wanted(target))


class EePoseFromJointPos(_Converter):
    """pd_joint_pos -> pd_ee_delta_pos / pd_ee_delta_pose (and their ``target`` modes): the tool-centre pose the
    recorded joint target puts the arm in (forward kinematics of the robot's pinocchio model), as a delta from the
    current pose (or the controller's kept target pose) in the controller's frame (ManiSkill's formula), clipped as
    ManiSkill clips it (position per axis, rotation by norm)."""

    def bind(self, unwrapped: Any) -> None:
        super().bind(unwrapped)
        self.pos_only = self.arm.config.frame == "root_translation"
        self.from_target = bool(self.arm.config.use_target)

    def _reference(self) -> Any:
        """The pose (sapien.Pose, in the controller's root-link frame) a delta action moves from: the controller's
        kept target, else the end effector's pose now."""
        return (self.arm._target_pose if self.from_target else self.arm.ee_pose_at_base).sp

    def __call__(self, action: np.ndarray) -> ConvertedAction:
        parts = self.source.to_action_dict(np.asarray(action))
        target = self._tool_pose(parts["arm"])
        arm = self._normalized(target)
        clipped = bool(np.abs(arm[:3]).max() > 1)
        arm[:3] = np.clip(arm[:3], -1.0, 1.0)
        if not self.pos_only and np.linalg.norm(arm[3:]) > 1:
            arm[3:] /= np.linalg.norm(arm[3:])
            clipped = True
        return ConvertedAction(self._join(parts, arm), clipped, np.r_[target.p, target.q])

    def _normalized(self, target: Any) -> np.ndarray:
        """The normalized action whose target pose (the controller's ``compute_target_pose``) is `target`: the
        position delta scaled into [-1, 1] by the position bounds; the rotation delta ``target * now⁻¹`` (applied
        before the current orientation, in the root frame) as the XYZ Euler angles the controller turns back into
        a rotation, divided by ``rot_lower`` as the controller multiplies by it (a negative bound: this is why
        ManiSkill's converter, which gives the axis-angle vector of ``now * target⁻¹``, turns the right way; its
        vector is right to first order only: 1e-3 rad off at 0.05 rad per step, measured). Both poses are taken in
        the frame of the controller's root link (Fetch's torso, not its base), as the controller takes them."""
        import torch
        from mani_skill.utils.geometry.rotation_conversions import (
            matrix_to_euler_angles,
            quaternion_to_matrix,
        )

        now = self._reference()
        self.root_at_action = self.arm.root_link.pose.sp
        target = self.root_at_action.inv() * target
        low = self.arm.action_space_low.cpu().numpy()[:3].astype(np.float64)
        high = self.arm.action_space_high.cpu().numpy()[:3].astype(np.float64)
        position = (np.asarray(target.p - now.p, np.float64) - 0.5 * (high + low)) / (0.5 * (high - low))
        if self.pos_only:
            return position
        q = torch.as_tensor(np.asarray((target * now.inv()).q, np.float64))[None]
        euler = matrix_to_euler_angles(quaternion_to_matrix(q), "XYZ")[0].numpy()
        return np.r_[position, euler / np.broadcast_to(np.asarray(self.arm.config.rot_lower, np.float64), 3)]
