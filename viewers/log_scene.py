"""Log the scene: each body's geometry once (static; meshes compacted: `simreel.viewers.mesh_compaction`), its pose
per step through `send_columns`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from simreel.viewers.mesh_compaction import compact_mesh
from simreel.viewers.paths import body_path
from simreel.viewers.poses import wxyz_to_xyzw
from simreel.viewers.scene_geometry import BodyGeometry, MeshPart, Primitive

__all__ = ["GHOST_ALPHA", "log_geometry", "log_pose_block", "log_static_poses"]

GHOST_ALPHA = 96
"""Opacity (0-255) of the replay's ghost."""
_GHOST_TINT = (140, 215, 255)
_MARKER_RADIUS = 0.012
_Y90 = np.array([0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5)])  # xyzw: +90° about y, maps +z onto +x


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of xyzw quaternions (broadcasting over leading axes)."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def _rotate_x(q_xyzw: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Each quaternion's local x axis scaled by `length`: (N, 3)."""
    x, y, z, w = np.moveaxis(q_xyzw, -1, 0)
    axis = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=-1)
    return axis * length[:, None]


def _colors(items: Sequence[Primitive | MeshPart], ghost: bool) -> np.ndarray:
    c = np.array([item.color for item in items], np.uint8).reshape(-1, 4)
    if ghost:
        c = c.copy()
        c[:, :3] = _GHOST_TINT
        c[:, 3] = GHOST_ALPHA
    return c


def _log_primitives(rec: rr.RecordingStream, path: str, prims: list[Primitive], ghost: bool) -> None:
    solid = rr.components.FillMode.Solid
    by_kind: dict[str, list[Primitive]] = {}
    for p in prims:
        by_kind.setdefault(p.kind, []).append(p)
    for kind, items in by_kind.items():
        size = np.array([p.size for p in items], np.float32)
        pose = np.array([p.pose for p in items], np.float64)
        centers, quats = pose[:, :3], wxyz_to_xyzw(pose[:, 3:])
        colors = _colors(items, ghost)
        if kind == "box":
            rec.log(path, rr.Boxes3D(half_sizes=size, centers=centers, quaternions=quats, colors=colors,
                                     fill_mode=solid), static=True)
        elif kind == "sphere":
            rec.log(path, rr.Ellipsoids3D(half_sizes=size, centers=centers, quaternions=quats, colors=colors,
                                          fill_mode=solid), static=True)
        elif kind == "capsule":  # SAPIEN: centred, along local x; Rerun: from the origin along +z
            q = _quat_mul(quats, _Y90)
            start = centers - _rotate_x(quats, size[:, 1].astype(np.float64))
            rec.log(path, rr.Capsules3D(lengths=2 * size[:, 1], radii=size[:, 0], translations=start,
                                        quaternions=q, colors=colors, fill_mode=solid), static=True)
        elif kind == "cylinder":  # SAPIEN: centred, along local x; Rerun: centred, along z
            rec.log(path, rr.Cylinders3D(lengths=2 * size[:, 1], radii=size[:, 0], centers=centers,
                                         quaternions=_quat_mul(quats, _Y90), colors=colors, fill_mode=solid),
                    static=True)


def _log_meshes(rec: rr.RecordingStream, path: str, meshes: list[MeshPart], ghost: bool) -> None:
    meshes = [compact_mesh(m) for m in meshes]
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    vertices = np.concatenate([m.vertices for m in meshes])
    triangles = np.concatenate([m.triangles + np.uint32(off) for m, off in zip(meshes, offsets[:-1], strict=True)])
    normals = None
    if all(m.normals is not None for m in meshes):
        normals = np.concatenate([m.normals for m in meshes])
    colors = np.repeat(np.array([m.color for m in meshes], np.uint8), np.diff(offsets), axis=0)
    albedo = None
    if ghost:
        albedo = (*_GHOST_TINT, GHOST_ALPHA)
    rec.log(path, rr.Mesh3D(vertex_positions=vertices, triangle_indices=triangles, vertex_normals=normals,
                            vertex_colors=colors[:, :3], albedo_factor=albedo), static=True)


def log_geometry(
    rec: rr.RecordingStream, root: str, geometry: list[BodyGeometry], *, ghost: bool = False,
    markers: Sequence[str] = (),
) -> None:
    """Log every body's shapes, static, at ``<root>/<body>``; a ghost is tinted and translucent.

    `markers`: bodies drawn as a small wireframe sphere because they have no shape (e.g. a goal site).
    """
    marker_set = set(markers)
    for body in geometry:
        path = body_path(root, body.name)
        if body.primitives:
            _log_primitives(rec, path, body.primitives, ghost)
        if body.meshes:
            _log_meshes(rec, path, body.meshes, ghost)
        if body.empty and body.name in marker_set and not ghost:
            rec.log(path, rr.Ellipsoids3D(half_sizes=[[_MARKER_RADIUS] * 3], colors=[(60, 200, 60, 255)],
                                          labels=[body.name], fill_mode=rr.components.FillMode.MajorWireframe),
                    static=True)


def log_static_poses(rec: rr.RecordingStream, root: str, names: Sequence[str], poses: np.ndarray) -> None:
    """One static transform per body: `poses` (B, 7) wxyz."""
    for name, pose in zip(names, poses, strict=True):
        rec.log(body_path(root, name),
                rr.Transform3D(translation=pose[:3], quaternion=rr.Quaternion(xyzw=wxyz_to_xyzw(pose[3:]))),
                static=True)


def log_pose_block(
    rec: rr.RecordingStream, root: str, names: Sequence[str], poses: np.ndarray, indexes: list[rr.TimeColumn]
) -> None:
    """Poses (R, B, 7) wxyz of `names` at the R time points of `indexes`, one `send_columns` per body."""
    xyzw = wxyz_to_xyzw(poses[..., 3:])
    for j, name in enumerate(names):
        rec.send_columns(
            body_path(root, name),
            indexes=indexes,
            columns=rr.Transform3D.columns(translation=poses[:, j, :3], quaternion=xyzw[:, j]),
        )
