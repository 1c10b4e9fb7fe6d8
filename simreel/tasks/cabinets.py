"""Procedural cabinets: a fixed body with 1-3 joints, drawers (prismatic) and knobs (revolute).

`sample_cabinet` draws a `CabinetSpec` from a numpy RandomState, `add_cabinet_links` builds it with a
ManiSkill articulation builder. The frame of the cabinet's root link is on the table at the middle of
the body's front face; drawers open towards -x (towards the robot), side by side along y. The link of
the drawer to open is named ``handle`` and its origin is the grasp point of its handle; other drawers
are ``drawer_<k>`` and knobs ``knob_<k>``. Every part has joint 0 a drawer, so a target always exists.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_DOF", "CabinetSpec", "add_cabinet_links", "sample_cabinet"]

MAX_DOF = 3
"""The most joints a cabinet has: the padded DOF of the merged articulation's state."""

SLOT_WIDTH = 0.13  # y distance between drawer centres
BODY_DEPTH = 0.2
DRAWER_DEPTH = 0.14
HANDLE_OUT = 0.07  # the handle sticks out this far in front of the drawer face
DRAWER_TRAVEL = 0.22  # joint limit of a drawer, metres
_BODY_COLOR = (0.55, 0.4, 0.3, 1.0)
_DRAWER_COLOR = (0.8, 0.65, 0.45, 1.0)
_HANDLE_COLOR = (0.15, 0.15, 0.15, 1.0)
_ROT_Z_180 = (0.0, 0.0, 0.0, 1.0)  # wxyz
_AXIS_X_TO_Z = (np.sqrt(0.5), 0.0, -np.sqrt(0.5), 0.0)  # wxyz: a joint frame whose x-axis points up


@dataclass(frozen=True)
class CabinetSpec:
    """One cabinet. ``joints`` lists ``"drawer"`` / ``"knob"`` per joint (joint 0 is a drawer);
    ``target`` indexes the drawer to open among the drawers (left to right)."""

    joints: tuple[str, ...]
    target: int
    handle_height: float  # z of the handles' grasp points above the table
    front_x: float  # x of the body's front face in the world

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def num_drawers(self) -> int:
        return self.joints.count("drawer")

    def drawer_y(self, k: int) -> float:
        return (k - (self.num_drawers - 1) / 2) * SLOT_WIDTH


def sample_cabinet(rng: np.random.RandomState) -> CabinetSpec:
    """Draw one cabinet: number of joints, their kinds, the target drawer, height and placement."""
    dof = int(rng.randint(1, MAX_DOF + 1))
    joints = ("drawer",) + tuple("drawer" if rng.rand() < 0.5 else "knob" for _ in range(dof - 1))
    target = int(rng.randint(joints.count("drawer")))
    return CabinetSpec(
        joints=joints,
        target=target,
        handle_height=float(rng.uniform(0.06, 0.14)),
        front_x=float(rng.uniform(0.08, 0.14)),
    )


def add_cabinet_links(builder, spec: CabinetSpec, handle_material) -> None:
    """Create the links and joints of ``spec`` in a ManiSkill ``ArticulationBuilder``."""
    import sapien

    builder.disable_self_collisions = True  # drawers sit inside the body; only the robot touches them
    width = max(spec.num_drawers, 1) * SLOT_WIDTH + 0.02
    drawer_half_h = 0.035
    top = spec.handle_height + drawer_half_h + 0.005

    body = builder.create_link_builder()
    body.set_name("body")
    half = [BODY_DEPTH / 2, width / 2, top / 2]
    pose = sapien.Pose(p=[BODY_DEPTH / 2, 0, top / 2])
    body.add_box_collision(pose, half_size=half)
    body.add_box_visual(pose, half_size=half, material=_BODY_COLOR)

    drawer_k = 0
    for j, kind in enumerate(spec.joints):
        if kind == "drawer":
            name = "handle" if drawer_k == spec.target else f"drawer_{j}"
            _add_drawer(builder, body, spec, _Slot(name, spec.drawer_y(drawer_k), drawer_half_h), handle_material)
            drawer_k += 1
        else:
            _add_knob(builder, body, f"knob_{j}", y=(j - 1) * 0.06 - 0.03, top=top)


@dataclass(frozen=True)
class _Slot:
    """Where a drawer goes: its link name, its centre across the body (y) and its half height."""

    name: str
    y: float
    half_h: float


def _add_drawer(builder, body, spec, slot: _Slot, handle_material) -> None:
    import sapien

    name, y, half_h = slot.name, slot.y, slot.half_h
    link = builder.create_link_builder(body)
    link.set_name(name)
    # the link's origin is the handle's grasp point, HANDLE_OUT / 2 in front of the drawer face
    grasp_x = -HANDLE_OUT / 2
    face_to_origin = HANDLE_OUT / 2
    drawer_half = [DRAWER_DEPTH / 2, SLOT_WIDTH / 2 - 0.01, half_h]
    drawer_pose = sapien.Pose(p=[face_to_origin + DRAWER_DEPTH / 2, 0, 0])
    link.add_box_collision(drawer_pose, half_size=drawer_half)
    link.add_box_visual(drawer_pose, half_size=drawer_half, material=_DRAWER_COLOR)
    handle_half = [HANDLE_OUT / 2, 0.008, 0.015]
    link.add_box_collision(sapien.Pose(), half_size=handle_half, material=handle_material)
    link.add_box_visual(sapien.Pose(), half_size=handle_half, material=_HANDLE_COLOR)
    link.set_joint_name(f"{name}_joint")
    link.set_joint_properties(
        "prismatic",
        limits=[[0.0, DRAWER_TRAVEL]],
        # the joint frame is turned 180° about z so that positive qpos pulls the drawer out (-x)
        pose_in_parent=sapien.Pose(p=[grasp_x, y, spec.handle_height], q=_ROT_Z_180),
        pose_in_child=sapien.Pose(q=_ROT_Z_180),
        friction=0.0,
        damping=2.0,
    )


def _add_knob(builder, body, name, y, top) -> None:
    import sapien

    link = builder.create_link_builder(body)
    link.set_name(name)
    upright = sapien.Pose(q=(np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0))
    link.add_cylinder_collision(upright, radius=0.02, half_length=0.01)
    link.add_cylinder_visual(upright, radius=0.02, half_length=0.01, material=_HANDLE_COLOR)
    bar = sapien.Pose(p=[0.012, 0, 0.012])
    link.add_box_visual(bar, half_size=[0.02, 0.004, 0.004], material=_DRAWER_COLOR)
    link.set_joint_name(f"{name}_joint")
    link.set_joint_properties(
        "revolute",
        limits=[[-np.pi / 2, np.pi / 2]],
        pose_in_parent=sapien.Pose(p=[BODY_DEPTH * 0.7, y, top + 0.01], q=_AXIS_X_TO_Z),
        pose_in_child=sapien.Pose(q=_AXIS_X_TO_Z),
        friction=0.0,
        damping=0.5,
    )
