"""Meshes made smaller before they are logged (`compact_mesh`): a robot's visual meshes come unwelded, every triangle
with three vertices of its own (the Panda's: 400k vertices for 136k triangles, 70k distinct positions), and they are
nearly all of a session's bytes.

Positions are snapped to a grid of `POSITION_STEP` (a quarter of a millimetre: finer than a pixel at any distance a
scene is looked at) and normals to one of `NORMAL_STEP`; corners at one position whose normals round to one bin
(`NORMAL_BINS`) become one vertex, with their mean normal. A smooth surface's corners merge, a sharp edge's do not
(their normals lie bins apart), so the surface is shaded as the scene's normals shade it. The triangles are the same
triangles. LZ4, which Rerun compresses chunks with, then finds repeats in the snapped numbers too: a 50-step
PickCube-v1 session is about half the size of one with the meshes as given (`benchmarks/bench_rrd_size.py`).
"""

from __future__ import annotations

import numpy as np

from simreel.viewers.scene_geometry import MeshPart

__all__ = ["POSITION_STEP", "NORMAL_STEP", "NORMAL_BINS", "compact_mesh"]

POSITION_STEP = 2.0**-12
"""The grid vertices are snapped to, in metres (0.24 mm; a power of two: snapped values stay exact in float32)."""
NORMAL_STEP = 2.0**-6
"""The grid each normal's components are snapped to (about 1° apart)."""
NORMAL_BINS = 3
"""Corners at one position become one vertex where each component of their normals rounds to the same multiple of
1/NORMAL_BINS."""


def compact_mesh(part: MeshPart) -> MeshPart:
    """`part` with its positions snapped, its corners at one position and of near normals merged, its triangles
    the same (by index into the merged vertices, in the order the triangles first use them)."""
    positions = np.round(np.asarray(part.vertices, np.float64) / POSITION_STEP) * POSITION_STEP
    normals = None if part.normals is None else np.nan_to_num(np.asarray(part.normals, np.float64))
    key = positions if normals is None else np.hstack([positions, np.round(normals * NORMAL_BINS)])
    _, first, merged = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    merged = rank[merged.reshape(-1)]
    vertices = positions[first[order]].astype(np.float32)
    return MeshPart(vertices, merged[np.asarray(part.triangles)].astype(np.uint32),
                    None if normals is None else _mean_normals(normals, merged, len(vertices)), part.color)


def _mean_normals(normals: np.ndarray, merged: np.ndarray, count: int) -> np.ndarray:
    """The unit mean of the normals of the corners merged into each of `count` vertices, snapped to `NORMAL_STEP`."""
    total = np.zeros((count, 3))
    np.add.at(total, merged, normals)
    length = np.linalg.norm(total, axis=1, keepdims=True)
    unit = np.divide(total, length, out=np.zeros_like(total), where=length > 0)
    return (np.round(unit / NORMAL_STEP) * NORMAL_STEP).astype(np.float32)
