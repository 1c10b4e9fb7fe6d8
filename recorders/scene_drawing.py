"""`SceneDrawing`: hands a writer what each sub-scene looks like, once per scene (when the recording starts and when a
reset rebuilds the scene), for a format that draws it for other viewers (`simreel.formats.writes_scene`: MCAP's
`/scene` and `/robot_description`)."""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from typing import Any

__all__ = ["SceneDrawing", "DRAWN_SUB_SCENES", "GEOMETRY_SOURCE"]

GEOMETRY_SOURCE = "collision"
"""The shapes written: PhysX's (boxes, spheres, capsules, convex hulls), the same with or without a render device and
small (PickCube-v1's scene ~32 KB in the file); its visual meshes would add ~1.9 MB."""
DRAWN_SUB_SCENES = 16
"""Sub-scenes whose geometry is written at most (the first ones): every sub-scene's frames share the origin, so
more draw nothing new; a GPU sim's thousands would make the file large."""


class SceneDrawing:
    """Reads sub-scenes' geometry from the live env (`simreel.sim.geometry.read_scene_geometry`) and gives it to
    `writer.write_scene`. A task whose shapes cannot be read is recorded without them, with one warning."""

    def __init__(self, writer: Any, unwrapped: Any, *, enabled: bool) -> None:
        self._writer = writer
        self._u = unwrapped
        self._enabled = enabled
        self._warned = False

    def send(self, envs: Iterable[int]) -> None:
        """The geometry of sub-scenes `envs` (those among the first `DRAWN_SUB_SCENES`), as they are now."""
        if not self._enabled:
            return
        from simreel.sim.geometry import read_scene_geometry

        for i in envs:
            if i >= DRAWN_SUB_SCENES:
                continue
            try:
                geometry = read_scene_geometry(self._u, env_idx=i, source=GEOMETRY_SOURCE)
            except Exception as e:  # noqa: BLE001 - a viewer's nicety must not stop a recording
                if not self._warned:
                    self._warned = True
                    warnings.warn(f"simreel: the shapes of {type(self._u).__name__}'s scene could not be read "
                                  f"({type(e).__name__}: {e}); the recording shows its frames without geometry",
                                  stacklevel=3)
                return
            self._writer.write_scene(geometry)
