"""`compact_mesh` on the meshes of a real PickCube-v1 scene (the Panda's visual meshes where a render device is, its
collision meshes elsewhere): the same triangles, each corner within half a grid step of where it was, its normal
within a few degrees of its own, and far fewer vertices."""

from __future__ import annotations

import numpy as np
import pytest

from simreel.sim.geometry import read_scene_geometry
from simreel.sim.make import make_env
from simreel.viewers.mesh_compaction import POSITION_STEP, compact_mesh


@pytest.fixture(scope="module")
def meshes():
    env = make_env("PickCube-v1")
    try:
        env.reset(seed=0)
        geometry = read_scene_geometry(env.unwrapped)
    finally:
        env.close()
    parts = [m for body in geometry.bodies if body.name.startswith("panda/") for m in body.meshes]
    assert parts
    return geometry.source, [(m, compact_mesh(m)) for m in parts]


def test_every_triangle_stays_where_it_was_to_half_a_grid_step(meshes):
    for original, compacted in meshes[1]:
        assert compacted.triangles.shape == original.triangles.shape and compacted.color == original.color
        corners_before = original.vertices[original.triangles].astype(np.float64)
        corners_after = compacted.vertices[compacted.triangles].astype(np.float64)
        assert np.abs(corners_after - corners_before).max() <= POSITION_STEP / 2 * (1 + 1e-6)
        assert compacted.triangles.max() < len(compacted.vertices)


def test_corners_keep_their_normals_and_merge_into_far_fewer_vertices(meshes):
    source, meshes = meshes
    changes = []
    for original, compacted in meshes:
        before = np.nan_to_num(original.normals[original.triangles.reshape(-1)].astype(np.float64))
        after = compacted.normals[compacted.triangles.reshape(-1)].astype(np.float64)
        lengths = np.linalg.norm(before, axis=1) * np.linalg.norm(after, axis=1)
        shown = lengths > 0.25  # (a degenerate corner has no normal to keep)
        cos = (before[shown] * after[shown]).sum(axis=1) / lengths[shown]
        changes.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    degrees = np.concatenate(changes)
    # merged corners' normals round to one bin of 1/3 per component: a few degrees apart at most, a sharp edge's
    # corners (normals bins apart) are not merged
    assert np.percentile(degrees, 50) < 3 and np.percentile(degrees, 99) < 10 and degrees.max() < 25
    vertices_before = sum(len(original.vertices) for original, _ in meshes)
    vertices_after = sum(len(compacted.vertices) for _, compacted in meshes)
    # the visual meshes come unwelded (three vertices a triangle); PhysX's convex collision meshes share theirs
    assert vertices_after < (vertices_before / 2 if source == "visual" else vertices_before + 1)
