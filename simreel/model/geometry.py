"""What the bodies of a scene look like: boxes, spheres, capsules, cylinders and triangle meshes in each body's own
frame, as plain data. `simreel.sim.geometry` reads them from a live scene; the viewers draw them, and the MCAP writer
writes them once per scene for Foxglove and Rerun (`simreel.formats.mcap.scene`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["RGBA", "Primitive", "MeshPart", "BodyGeometry", "SceneGeometry"]

RGBA = tuple[int, int, int, int]


@dataclass(frozen=True)
class Primitive:
    """A box, sphere, capsule or cylinder in the body frame.

    ``size``: box half sizes (x, y, z); sphere (r, r, r); capsule and cylinder (radius, half length, 0) with
    the axis along local x, as in SAPIEN. ``pose``: ``[x y z qw qx qy qz]`` of the shape in the body frame.
    """

    kind: str
    size: tuple[float, float, float]
    pose: tuple[float, ...]
    color: RGBA


@dataclass
class MeshPart:
    """A triangle mesh in the body frame (the shape's local pose and scale already applied)."""

    vertices: np.ndarray
    """(N, 3) float32"""
    triangles: np.ndarray
    """(M, 3) uint32"""
    normals: np.ndarray | None
    """(N, 3) float32 or None"""
    color: RGBA


@dataclass
class BodyGeometry:
    """Everything drawn for one body, in its own frame."""

    name: str
    primitives: list[Primitive] = field(default_factory=list)
    meshes: list[MeshPart] = field(default_factory=list)
    world_pose: tuple[float, ...] | None = None
    """``[x y z qw qx qy qz]`` of a static body, where it stays (None for a body that moves, or not read): a static
    actor outside the state dict has no recorded pose to be drawn at."""

    @property
    def empty(self) -> bool:
        return not self.primitives and not self.meshes


@dataclass
class SceneGeometry:
    """The geometry of every body of one sub-scene (`env_idx`), read once per scene (`simreel.sim.geometry`)."""

    env_idx: int
    source: str
    """``visual`` (render shapes) or ``collision`` (PhysX shapes: an env built without a render device)."""
    bodies: list[BodyGeometry]
