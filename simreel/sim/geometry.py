"""What to draw: every body of a live scene, with its shapes in its own frame (`simreel.model.geometry`).

The bodies of one sub-scene by simreel's names are `simreel.sim.describe.scene_bodies` (the scene fingerprint lists
the same bodies). `body_geometry` reads a body's shapes: collision shapes (``sapien.physx.PhysxCollisionShape*``) or
visual shapes (render components, present only when the env was built with a render device). The viewers draw what
`scene_geometry` reads; a recorder hands `read_scene_geometry`'s plain data to its writer (the MCAP format writes it
once per scene).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simreel.model.geometry import RGBA, BodyGeometry, MeshPart, Primitive, SceneGeometry
from simreel.sim.describe import SceneBody, scene_bodies

__all__ = ["GEOMETRY_SOURCES", "PLANE_HALF_SIZE", "body_geometry", "scene_geometry", "read_scene_geometry"]

GEOMETRY_SOURCES = ("auto", "visual", "collision")
PLANE_HALF_SIZE = 1.5
"""Half the side of the square drawn for an infinite plane (the ground), metres."""

_ROBOT_GREY: RGBA = (205, 208, 214, 255)
_STATIC_COLORS: dict[str, RGBA] = {"ground": (150, 150, 150, 255)}
_KINEMATIC_COLOR: RGBA = (196, 164, 122, 255)
_PALETTE: tuple[RGBA, ...] = (
    (228, 26, 28, 255),
    (55, 126, 184, 255),
    (77, 175, 74, 255),
    (255, 127, 0, 255),
    (152, 78, 163, 255),
    (166, 86, 40, 255),
    (247, 129, 191, 255),
    (0, 170, 170, 255),
)
"""Colours for bodies when the env has no render components (collision geometry)."""


# ----------------------------------------------------------------------------------------------- shapes
def _pose7(pose: Any) -> tuple[float, ...]:
    return tuple(float(x) for x in (*pose.p, *pose.q))


def _transform(vertices: np.ndarray, pose: Any, scale: Any = None) -> np.ndarray:
    v = np.asarray(vertices, np.float64)
    if scale is not None:
        v = v * np.asarray(scale, np.float64)
    return (v @ np.asarray(pose.to_transformation_matrix())[:3, :3].T + np.asarray(pose.p)).astype(np.float32)


def _rotate(normals: np.ndarray, pose: Any) -> np.ndarray:
    return (np.asarray(normals, np.float64) @ np.asarray(pose.to_transformation_matrix())[:3, :3].T).astype(np.float32)


def _mesh_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    import trimesh

    mesh = trimesh.Trimesh(vertices=vertices, faces=triangles, process=False)
    return np.asarray(mesh.vertex_normals, np.float32)


def _plane_square(pose: Any, color: RGBA) -> MeshPart:
    """A finite square of an infinite plane: PhysX planes are x = 0 in their local frame (normal +x)."""
    h = PLANE_HALF_SIZE
    local = np.array([[0, -h, -h], [0, h, -h], [0, h, h], [0, -h, h]], np.float32)
    tris = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    normals = _rotate(np.tile([1.0, 0.0, 0.0], (4, 1)), pose)
    return MeshPart(_transform(local, pose), tris, normals, color)


def _collision_geometry(entity: Any, color: RGBA) -> tuple[list[Primitive], list[MeshPart]]:
    import sapien.physx as physx

    prims: list[Primitive] = []
    meshes: list[MeshPart] = []
    for comp in entity.components:
        if not isinstance(comp, physx.PhysxRigidBaseComponent):
            continue
        for shape in comp.collision_shapes:
            pose = shape.local_pose
            if isinstance(shape, physx.PhysxCollisionShapeBox):
                prims.append(Primitive("box", tuple(float(x) for x in shape.half_size), _pose7(pose), color))
            elif isinstance(shape, physx.PhysxCollisionShapeSphere):
                r = float(shape.radius)
                prims.append(Primitive("sphere", (r, r, r), _pose7(pose), color))
            elif isinstance(shape, physx.PhysxCollisionShapeCapsule):
                prims.append(Primitive("capsule", (float(shape.radius), float(shape.half_length), 0.0), _pose7(pose), color))
            elif isinstance(shape, physx.PhysxCollisionShapeCylinder):
                prims.append(Primitive("cylinder", (float(shape.radius), float(shape.half_length), 0.0), _pose7(pose), color))
            elif isinstance(shape, (physx.PhysxCollisionShapeConvexMesh, physx.PhysxCollisionShapeTriangleMesh)):
                vertices = _transform(shape.vertices, pose, shape.scale)
                tris = np.asarray(shape.triangles, np.uint32)
                meshes.append(MeshPart(vertices, tris, _mesh_normals(vertices, tris), color))
            elif isinstance(shape, physx.PhysxCollisionShapePlane):
                meshes.append(_plane_square(pose, color))
    return prims, meshes


def _texture_mean(texture: Any) -> np.ndarray:
    """Mean RGB (0-1) of a texture, used to tint a mesh that Rerun receives without its texture."""
    try:
        pixels = np.asarray(texture.download())
    except Exception:  # a texture that cannot be read back: no tint
        return np.ones(3)
    if pixels.ndim != 3 or pixels.shape[-1] < 3:
        return np.ones(3)
    rgb = pixels[::8, ::8, :3].reshape(-1, 3).astype(np.float64).mean(axis=0)
    return rgb / 255.0 if pixels.dtype == np.uint8 else np.clip(rgb, 0.0, 1.0)


def _rgba(material: Any, fallback: RGBA) -> RGBA:
    """A render material's base colour (times the mean of its base colour texture) as RGBA bytes."""
    if material is None:
        return fallback
    c = np.clip(np.asarray(material.base_color, np.float64), 0.0, 1.0)[:4]
    texture = getattr(material, "base_color_texture", None)
    if texture is not None:
        c = np.concatenate([c[:3] * _texture_mean(texture), c[3:]])
    return tuple(int(round(x * 255)) for x in c)  # type: ignore[return-value]


def _render_primitive(shape: Any, color: RGBA) -> Primitive | None:
    """A box, sphere, capsule or cylinder render shape as a primitive; None for meshes and planes."""
    import sapien.render as render

    pose = _pose7(shape.local_pose)
    if isinstance(shape, render.RenderShapeBox):
        return Primitive("box", tuple(float(x) for x in shape.half_size), pose, color)
    if isinstance(shape, render.RenderShapeSphere):
        r = float(shape.radius)
        return Primitive("sphere", (r, r, r), pose, color)
    if isinstance(shape, render.RenderShapeCapsule):
        return Primitive("capsule", (float(shape.radius), float(shape.half_length), 0.0), pose, color)
    if isinstance(shape, render.RenderShapeCylinder):
        return Primitive("cylinder", (float(shape.radius), float(shape.half_length), 0.0), pose, color)
    return None


def _render_mesh_parts(shape: Any, color: RGBA) -> list[MeshPart]:
    """A triangle-mesh (or plane) render shape's parts, each with its own material."""
    pose = shape.local_pose
    scale = getattr(shape, "scale", None)
    parts = []
    for part in shape.parts:
        vertices = _transform(part.vertices, pose, scale)
        tris = np.asarray(part.triangles, np.uint32)
        if len(vertices) == 0 or len(tris) == 0:
            continue
        normals = np.asarray(part.vertex_normal, np.float32) if hasattr(part, "vertex_normal") else None
        if normals is None or normals.shape != vertices.shape:
            normals = _mesh_normals(vertices, tris)
        else:
            normals = _rotate(normals, pose)
        parts.append(MeshPart(vertices, tris, normals, _rgba(part.material, color)))
    return parts


def _visual_geometry(entity: Any, fallback: RGBA) -> tuple[list[Primitive], list[MeshPart]]:
    import sapien.render as render

    prims: list[Primitive] = []
    meshes: list[MeshPart] = []
    for comp in entity.components:
        if not isinstance(comp, render.RenderBodyComponent):
            continue
        for shape in comp.render_shapes:
            try:
                color = _rgba(shape.material, fallback)
            except RuntimeError:  # a mesh whose parts have different materials: each part says its own
                color = fallback
            prim = _render_primitive(shape, color)
            if prim is not None:
                prims.append(prim)
            else:
                meshes += _render_mesh_parts(shape, color)
    return prims, meshes


def _has_plane(entity: Any) -> bool:
    import sapien.physx as physx

    return any(
        isinstance(shape, physx.PhysxCollisionShapePlane)
        for comp in entity.components
        if isinstance(comp, physx.PhysxRigidBaseComponent)
        for shape in comp.collision_shapes
    )


def _default_color(body: SceneBody, index: int) -> RGBA:
    if body.group == "robot":
        return _ROBOT_GREY
    if body.body_type == "static":
        return _STATIC_COLORS.get(body.name, (170, 170, 170, 255))
    if body.body_type == "kinematic":
        return _KINEMATIC_COLOR
    return _PALETTE[index % len(_PALETTE)]


def body_geometry(body: SceneBody, *, source: str, color: RGBA) -> BodyGeometry:
    """The shapes of one body: ``source="visual"`` (render shapes) or ``"collision"`` (physx shapes).

    Planes are always drawn from their collision shape, as a finite square (the visual ground is a huge mesh).
    """
    if source not in ("visual", "collision"):
        raise ValueError(f"geometry source must be 'visual' or 'collision', got {source!r}")
    if source == "visual" and not _has_plane(body.entity):
        prims, meshes = _visual_geometry(body.entity, color)
    else:
        prims, meshes = _collision_geometry(body.entity, color)
    return BodyGeometry(body.name, prims, meshes)


def scene_geometry(unwrapped: Any, bodies: list[SceneBody], *, source: str = "auto") -> tuple[str, list[BodyGeometry]]:
    """(source used, geometry of every body). ``auto``: visual shapes when the scene can render, else collision."""
    if source not in GEOMETRY_SOURCES:
        raise ValueError(f"geometry source must be one of {GEOMETRY_SOURCES}, got {source!r}")
    can_render = bool(unwrapped.scene.can_render()) if hasattr(unwrapped.scene, "can_render") else False
    if source == "auto":
        source = "visual" if can_render else "collision"
    elif source == "visual" and not can_render:
        source = "collision"
    out = []
    palette_index = 0
    for body in bodies:
        color = _default_color(body, palette_index)
        if body.group != "robot" and body.body_type == "dynamic":
            palette_index += 1
        out.append(body_geometry(body, source=source, color=color))
    return source, out


def read_scene_geometry(unwrapped: Any, *, env_idx: int = 0, source: str = "auto") -> SceneGeometry:
    """The geometry of every body of sub-scene `env_idx` of a live env, each static one with its world pose (what a
    writer keeps of a scene: plain data, no sapien object)."""
    bodies = scene_bodies(unwrapped, env_idx=env_idx)
    used, geometry = scene_geometry(unwrapped, bodies, source=source)
    for body, geo in zip(bodies, geometry, strict=True):
        if body.body_type == "static":
            geo.world_pose = _pose7(body.entity.pose)
    return SceneGeometry(env_idx, used, geometry)
