"""What to draw: the core's `simreel.sim.geometry` (reading shapes from a live scene), `simreel.model.geometry` (the
shapes as plain data) and `simreel.sim.describe.scene_bodies`, under the names the viewers import them by."""

from simreel.model.geometry import BodyGeometry, MeshPart, Primitive
from simreel.sim.describe import SceneBody, scene_bodies
from simreel.sim.geometry import GEOMETRY_SOURCES, PLANE_HALF_SIZE, body_geometry, scene_geometry

__all__ = [
    "GEOMETRY_SOURCES",
    "PLANE_HALF_SIZE",
    "Primitive",
    "MeshPart",
    "BodyGeometry",
    "SceneBody",
    "scene_bodies",
    "body_geometry",
    "scene_geometry",
]
