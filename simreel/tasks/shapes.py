"""Procedural graspable objects: boxes, cylinders, capsules and convex hulls of random point sets.

`sample_object` draws an `ObjectSpec` from a numpy RandomState (one per sub-scene: the task's batched
episode RNG), `add_object_shapes` adds its collision and visual shapes to a ManiSkill actor builder.
Every object fits the Panda gripper (at most 7 cm across the fingers at any yaw the tasks use).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["OBJECT_KINDS", "ObjectSpec", "add_object_shapes", "sample_object"]

OBJECT_KINDS = ("box", "cylinder", "capsule", "hull")
_COLORS = {
    "box": (0.85, 0.25, 0.2, 1.0),
    "cylinder": (0.2, 0.5, 0.85, 1.0),
    "capsule": (0.95, 0.7, 0.15, 1.0),
    "hull": (0.35, 0.75, 0.35, 1.0),
}
_UPRIGHT = (np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0)  # wxyz: SAPIEN's x-axis cylinder stood up along z


@dataclass(frozen=True)
class ObjectSpec:
    """One procedurally generated object. Lengths in metres, density in kg/m³.

    ``size``: box half sizes (x, y, z); cylinder (radius, half length, -); capsule (radius, half length
    of the straight part, -); hull: half extents of the box the random points were drawn from.
    ``rest_z``: height of the object's origin when it rests on the table in its build orientation.
    """

    kind: str
    size: tuple[float, float, float]
    density: float
    rest_z: float
    hull_vertices: np.ndarray | None = field(default=None, compare=False, repr=False)

    @property
    def mass(self) -> float:
        return self.density * self.volume

    @property
    def volume(self) -> float:
        a, b, c = self.size
        if self.kind == "box":
            return 8 * a * b * c
        if self.kind == "cylinder":
            return np.pi * a * a * 2 * b
        if self.kind == "capsule":
            return np.pi * a * a * 2 * b + 4 / 3 * np.pi * a**3
        import trimesh

        return float(trimesh.convex.convex_hull(self.hull_vertices).volume)


def sample_object(rng: np.random.RandomState) -> ObjectSpec:
    """Draw one object: kind, size and density all from ``rng`` (the same draws on any machine)."""
    kind = OBJECT_KINDS[rng.randint(len(OBJECT_KINDS))]
    density = float(rng.uniform(200, 1200))
    if kind == "box":
        size = (rng.uniform(0.015, 0.025), rng.uniform(0.015, 0.025), rng.uniform(0.015, 0.03))
        return ObjectSpec(kind, _floats(size), density, rest_z=float(size[2]))
    if kind == "cylinder":
        radius, half_length = rng.uniform(0.015, 0.025), rng.uniform(0.015, 0.03)
        return ObjectSpec(kind, _floats((radius, half_length, 0.0)), density, rest_z=float(half_length))
    if kind == "capsule":
        radius, half_length = rng.uniform(0.015, 0.02), rng.uniform(0.015, 0.025)
        return ObjectSpec(kind, _floats((radius, half_length, 0.0)), density, rest_z=float(radius))
    import trimesh

    half = np.array([rng.uniform(0.018, 0.025), rng.uniform(0.018, 0.025), rng.uniform(0.015, 0.03)])
    points = rng.uniform(-1.0, 1.0, size=(24, 3)) * half
    hull = trimesh.convex.convex_hull(points)
    vertices = np.asarray(hull.vertices, dtype=np.float32)
    vertices -= vertices.mean(axis=0)  # origin at the vertex centroid, close to the grasp point
    return ObjectSpec(
        kind, _floats(half), density, rest_z=float(-vertices[:, 2].min()), hull_vertices=vertices
    )


def add_object_shapes(builder, spec: ObjectSpec, material) -> None:
    """Add the collision shape (with ``material``, a PhysxMaterial) and a visual of ``spec`` to ``builder``."""
    import sapien

    color = _COLORS[spec.kind]
    a, b, c = spec.size
    if spec.kind == "box":
        builder.add_box_collision(half_size=spec.size, material=material, density=spec.density)
        builder.add_box_visual(half_size=spec.size, material=color)
    elif spec.kind == "cylinder":
        pose = sapien.Pose(q=_UPRIGHT)
        builder.add_cylinder_collision(pose, radius=a, half_length=b, material=material, density=spec.density)
        builder.add_cylinder_visual(pose, radius=a, half_length=b, material=color)
    elif spec.kind == "capsule":
        builder.add_capsule_collision(radius=a, half_length=b, material=material, density=spec.density)
        builder.add_capsule_visual(radius=a, half_length=b, material=color)
    else:
        path = str(_mesh_file(spec.hull_vertices))
        builder.add_convex_collision_from_file(path, material=material, density=spec.density)
        builder.add_visual_from_file(path, material=color)


def _floats(values) -> tuple[float, float, float]:
    return tuple(float(v) for v in values)


def _mesh_file(vertices: np.ndarray) -> Path:
    """The convex hull of ``vertices`` as an .obj file in a cache folder (SAPIEN loads meshes from files).

    Named by a hash of the vertices, so the same object reuses the same file; written atomically.
    """
    import trimesh

    digest = hashlib.sha1(np.ascontiguousarray(vertices, dtype=np.float32).tobytes()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / "simreel-meshes"
    path = folder / f"hull-{digest}.obj"
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{path.name}.{os.getpid()}.tmp"
        trimesh.convex.convex_hull(vertices).export(tmp, file_type="obj")
        os.replace(tmp, path)
    return path
