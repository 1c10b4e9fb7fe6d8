"""Is a converted episode the same trajectory? Its per-step tracking errors against the original, judged.

A control-mode conversion changes the actions, so the robot's joint values and velocities are not expected to
match the original's exactly; what must match is what the task sees. Compared at every state row (row 0 after
the reset, row t+1 after step t) of the original (its recorded states) and of the converted run:

    command/<link>[p], [q]             per step: the tool-centre pose the converted action commanded (the arm
                                       controller's target) against the one the recorded action commanded: a
                                       wrong conversion shows at its own step, before the arm lags behind it (not
                                       judged at steps whose action the target mode's limits clipped)
                                                                               cmd_pos (m), cmd_rot (rad)
    ee/<link>[p], [q]                  the tool-centre pose (forward kinematics of each row's robot state;
                                       rotation as an angle, q == -q)          groups ee_pos (m), ee_rot (rad)
    env_states/actors/<a>[p], [q]      every actor's pose                      obj_pos (m), obj_rot (rad)
    env_states/articulations/<a>[...]  every other articulation's root pose and joint positions (a drawer)
                                                                               obj_pos, obj_rot, obj_qpos
    success                            per step: how many steps from the nearest step at which the original's
                                       success has the converted one's value (0 where they agree; inf where the
                                       original never has it)                  success (steps)

Velocities are not compared (other controllers reach the same poses with other velocities). The verdict uses
`simreel.verdicts.compare.ErrorTable`, the rules of `simreel replay`: ``exact``, ``within_tolerance``, or ``diverged``
with the first step at which a value leaves its tolerance.

Default tolerances, measured on ManiSkill's CPU sim with pd_joint_pos demos recorded by RecordEpisode (PickCube
grasp-and-lift demos planned with IK; smooth joint paths through waypoints within ±15% of each joint's range for
StackCube, PegInsertionSide and SimreelHeteroDrawer's cabinets), 8 episodes of 60 steps per task, converted to
pd_joint_delta_pos and to pd_ee_delta_pose, over the episodes whose actions were never clipped
(`benchmarks/measure_tracking.py` prints this table; the same run with ±20% waypoints in brackets):

    group     largest seen (joint / ee target)               default   why
    cmd_pos   1.5e-8 / 3.6e-7 m                              1e-4 m    the command is the conversion itself: float
    cmd_rot   2.9e-8 / 2.8e-7 rad                            1e-3 rad    rounding only, so a wrong conversion shows
                                                                         at its own step
    ee_pos    8.5e-4 / 7.2e-4 m     [2.4e-3 / 5.5e-3]        1e-2 m    the arm's path: an end-effector controller
    ee_rot    1.7e-3 / 4.3e-3 rad   [4.3e-3 / 1.6e-2]        0.05 rad    reaches the same target through other joint
                                                                         values (a redundant arm), and contact
                                                                         amplifies float-sized differences (StackCube:
                                                                         2.4 mm with commands equal to 1.5e-8)
    obj_pos   6.4e-7 / 1.8e-4 m                              2e-3 m    objects are what the task is about: ~10x
    obj_rot   3.1e-5 / 6.4e-4 rad                            1e-2 rad
    obj_qpos  0 / 0 (no drawer was moved)                    2e-3      as obj_pos
    success   0 / 1 step                                     1 step    a threshold crossing moved by one step

"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.errors import UsageError
from simreel.model.blocks import StepBlock
from simreel.model.components import Component, Tolerances, component_error, components_of
from simreel.model.fields import field_group
from simreel.replay.convert.options import TRACKING_GROUPS
from simreel.verdicts.compare import CompareScope, EpisodeComparison, ErrorTable

__all__ = ["TRACKING_GROUPS", "DEFAULT_TRACKING_TOLERANCES", "Commands", "EndEffector", "tracking_tolerances",
           "TrackingBlocks", "success_timing"]

DEFAULT_TRACKING_TOLERANCES: dict[str, float] = {
    "cmd_pos": 1e-4, "cmd_rot": 1e-3, "ee_pos": 1e-2, "ee_rot": 0.05, "obj_pos": 2e-3, "obj_rot": 0.01,
    "obj_qpos": 2e-3, "success": 1.0,
}
"""Tolerance per group (see the module docstring for how they were measured)."""
_OBJECT_GROUPS = {"pos": "obj_pos", "quat": "obj_rot", "qpos": "obj_qpos"}


def tracking_tolerances(groups: Mapping[str, float] | None = None) -> Tolerances:
    """The defaults, with `groups` (``{"ee_pos": 1e-3}``) overriding single ones."""
    values = dict(DEFAULT_TRACKING_TOLERANCES)
    for group, value in (groups or {}).items():
        if group not in values:
            raise UsageError(f"unknown tracking tolerance group {group!r}; expected one of {', '.join(TRACKING_GROUPS)}")
        values[group] = value
    try:  # the tolerances' own rule (`simreel.verdicts.compare`): finite numbers >= 0
        return Tolerances(values)
    except ValueError as e:
        raise UsageError(f"tracking {e}") from None


class EndEffector:
    """The robot's tool-centre pose computed from state rows: its pinocchio model, the robot's state key, the
    link. Bind it to a live env (after each reset: a reset may rebuild the robot)."""

    def __init__(self, unwrapped: Any) -> None:
        agent = unwrapped.agent
        self.robot_key = f"articulations/{agent.robot.name}"
        link = getattr(agent, "tcp", None) or agent.robot.links[-1]
        self.link_name = link.name
        self.link_index = int(link.index.item())
        self.model = agent.robot.create_pinocchio_model()

    @property
    def key(self) -> str:
        return f"ee/{self.link_name}"

    def poses(self, robot_rows: np.ndarray) -> np.ndarray:
        """(N, 7) world poses ``[x y z qw qx qy qz]`` of the link for (N, 13 + 2·DOF) articulation state rows."""
        import sapien

        rows = np.asarray(robot_rows, np.float64)
        dof = (rows.shape[1] - 13) // 2
        out = np.zeros((rows.shape[0], 7))
        for k, row in enumerate(rows):
            self.model.compute_forward_kinematics(row[13 : 13 + dof])
            pose = sapien.Pose(row[:3], row[3:7]) * self.model.get_link_pose(self.link_index)
            out[k, :3], out[k, 3:] = pose.p, pose.q
        return out


def success_timing(original: np.ndarray, converted: np.ndarray) -> np.ndarray:
    """Per step: 0 where the two agree, else how many steps away the nearest step is at which `original` has the
    converted value (a success that comes one step late or early: 1; one the original never has: inf)."""
    original, converted = np.asarray(original, bool), np.asarray(converted, bool)
    out = np.zeros(len(original))
    steps = np.arange(len(original))
    for t in np.flatnonzero(original != converted):
        same = steps[original == converted[t]]
        out[t] = np.abs(same - t).min() if same.size else np.inf
    return out


def _pose_errors(key: str, poses: tuple[np.ndarray, np.ndarray],
                 groups: tuple[str, str]) -> list[tuple[str, np.ndarray, str]]:
    """(key, per-row error, group) of the position and rotation errors of two (N, 7) pose arrays: `key[p]`, `key[q]`."""
    a, b = poses
    return [(f"{key}[p]", component_error(a, b, Component(f"{key}[p]", groups[0], 0, 3)), groups[0]),
            (f"{key}[q]", component_error(a, b, Component(f"{key}[q]", groups[1], 3, 7, quat=True)), groups[1])]


@dataclass(frozen=True)
class Commands:
    """What a converted run commanded: `poses` (T, 2, 7), per step the tool-centre pose the recorded and the
    converted action commanded; `clipped`, the steps at which the target mode could not command the recorded
    target (their command error is the part out of reach: not judged; the trajectory is)."""

    poses: np.ndarray
    clipped: tuple[int, ...] = ()


class TrackingBlocks:
    """The tracking errors of a converted run against its original, a block of rows at a time (`reset`, then `steps`
    for each block in order, each the original's rows and the converted run's): each block's per-row errors are kept
    (the original's and the run's rows are not), and the success flags (a bool a step: success timing looks along
    the whole episode). `comparison(commands)` judges them all with the commands. `ee`: bound to the converted
    run's env after its reset."""

    def __init__(self, ee: EndEffector, tolerances: Tolerances, *, initial: bool = True) -> None:
        self.ee, self.tolerances, self.initial = ee, tolerances, initial
        self._parts: dict[str, tuple[str, list[np.ndarray]]] = {}
        """State row errors: key -> (group, the errors of each block so far)."""
        self._success: tuple[list[np.ndarray], list[np.ndarray]] | None = ([], [])
        """The original's and the run's success flags so far; None when either lacks them."""

    def reset(self, original: StepBlock, converted: StepBlock) -> None:
        """Row 0: the states right after the reset."""
        self._states(original, converted)

    def steps(self, original: StepBlock, converted: StepBlock) -> None:
        """The next block of steps (its state rows: after those steps)."""
        if original.rows != converted.rows:
            raise ValueError(f"a block of {original.rows} original steps was converted as {converted.rows}")
        self._states(original, converted)
        flags = original.get("success"), converted.get("success")
        if self._success is not None and all(f is not None for f in flags):
            for kept, rows in zip(self._success, flags, strict=True):
                kept.append(np.asarray(rows, bool))
        else:
            self._success = None

    def _states(self, original: StepBlock, converted: StepBlock) -> None:
        rec, conv = field_group(original.arrays, "env_states"), field_group(converted.arrays, "env_states")
        ee, errors = self.ee, []
        if ee.robot_key in rec and ee.robot_key in conv:
            errors += _pose_errors(ee.key, (ee.poses(rec[ee.robot_key]), ee.poses(conv[ee.robot_key])),
                                   ("ee_pos", "ee_rot"))
        for path, rows in rec.items():
            if path == ee.robot_key or path.startswith("controller/") or path not in conv:
                continue
            for comp in components_of(path, rows.shape[1:]):
                group = _OBJECT_GROUPS.get(comp.group)
                if group is not None:
                    errors.append((comp.key, component_error(rows, conv[path], comp), group))
        for key, err, group in errors:
            self._parts.setdefault(key, (group, []))[1].append(err)

    def comparison(self, commands: Commands | None = None) -> EpisodeComparison:
        """The judged errors of every block so far, with the commands' (`commands`: of the whole episode)."""
        table = ErrorTable(self.tolerances, CompareScope(initial=self.initial))
        if _commands_judged(commands):
            judged = commands.poses.copy()
            judged[list(commands.clipped), 1] = judged[list(commands.clipped), 0]
            for key, err, group in _pose_errors(f"command/{self.ee.link_name}", (judged[:, 0], judged[:, 1]),
                                                ("cmd_pos", "cmd_rot")):
                table.add(key, err, group, per_state=False)
        for key, (group, parts) in self._parts.items():
            table.add(key, np.concatenate(parts), group, per_state=True)
        if self._success is not None:
            original, converted = (np.concatenate(flags) if flags else np.zeros(0, bool) for flags in self._success)
            table.add("success", success_timing(original, converted), "success", per_state=False)
        return table.comparison()


def _commands_judged(commands: Commands | None) -> bool:
    """Whether the commands are judged: every step has both poses and the target mode reached some step's target (an
    episode clipped at every step has no command error to judge, and its report says so: no command keys)."""
    return (commands is not None and not np.isnan(commands.poses).any()
            and len(set(commands.clipped)) < len(commands.poses))

