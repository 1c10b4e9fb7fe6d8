"""Let ManiSkill build state-only envs on a machine with no render device at all.

ManiSkill 3.0.1 with ``render_backend="none"`` already skips render bodies, lights and cameras, but scene
building still *constructs* render materials and textures eagerly (``actors.build_cube``, sapien's URDF loader,
the MJCF loader, ``ActorBuilder.add_*_visual`` defaults, ...), and each construction raises
``RuntimeError: failed to find a rendering device``. Nothing ever uses those objects without a renderer, so
this module swaps the three classes for inert stand-ins that just keep their attributes:
`InertRenderMaterial`, `InertRenderTexture2D`, `InertRenderTexture`.

The swap (`install`) is made only when creating a real ``RenderMaterial`` fails, so it never changes a process
that can render. It replaces the class wherever a module holds it: ``sapien.render``, ``sapien.pysapien.render``
(sapien's ``actor_builder.py`` imports ``sapien.pysapien`` under the name ``sapien``), and every loaded module that
bound the name at import (``sapien.wrapper.urdf_loader``, ``mani_skill.utils.building._mjcf_loader``, user
task modules). It cannot be undone in the same process, and needs none: without a device no real one can exist.

Written against mani-skill 3.0.1 and sapien 3.0.3; other versions get one warning. Tasks that read render
shapes to build their scene (PushT-v1) cannot work without rendering: `check_task` raises
`RenderUnavailableError` for them before anything is built.
"""

from __future__ import annotations

import sys
import warnings
from typing import Any

from simreel.errors import RenderUnavailableError

__all__ = [
    "PINNED_VERSIONS",
    "TASKS_NEEDING_RENDER",
    "NoRenderVersionWarning",
    "InertRenderMaterial",
    "InertRenderTexture2D",
    "InertRenderTexture",
    "check_task",
    "install",
    "is_installed",
]

PINNED_VERSIONS = {"mani-skill": "3.0.1", "sapien": "3.0.3"}
"""The versions this layer was written and tested against."""

TASKS_NEEDING_RENDER = {
    "PushT-v1": "it un-textures the table by reading the render shapes of its render body, which is never built "
    "without a render device",
}
"""Tasks known not to build without a render device, with the reason."""

_CLASS_NAMES = ("RenderMaterial", "RenderTexture2D", "RenderTexture")


class NoRenderVersionWarning(UserWarning):
    """mani-skill or sapien is not the version the no-render layer was written for."""


class _Inert:
    """Keeps whatever is set on it; ``set_x(v)`` / ``get_x()`` work like the real classes' accessors."""

    _defaults: dict[str, Any] = {}

    def __init__(self, **kwargs: Any) -> None:
        for key, value in {**self._defaults, **kwargs}.items():
            object.__setattr__(self, key, value)

    def __getattr__(self, name: str) -> Any:
        # Only reached for attributes never set.
        if name.startswith("set_"):
            return lambda value: object.__setattr__(self, name[4:], value)
        if name.startswith("get_"):
            return lambda: getattr(self, name[4:])
        if name.startswith("_"):
            raise AttributeError(name)
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}(inert, no render device)"


class InertRenderMaterial(_Inert):
    """Stand-in for ``sapien.render.RenderMaterial``: same constructor keywords and defaults, renders nothing."""

    _defaults = {
        "emission": [0.0, 0.0, 0.0, 0.0],
        "base_color": [1.0, 1.0, 1.0, 1.0],
        "specular": 0.0,
        "roughness": 1.0,
        "metallic": 0.0,
        "transmission": 0.0,
        "ior": 1.45,
        "transmission_roughness": 0.0,
    }


class InertRenderTexture2D(_Inert):
    """Stand-in for ``sapien.render.RenderTexture2D`` (from a file or an array); loads nothing."""

    def __init__(self, array: Any = None, format: str | None = None, *, filename: str | None = None,
                 **kwargs: Any) -> None:
        if isinstance(array, str) and filename is None:  # RenderTexture2D("path.png")
            array, filename = None, array
        super().__init__(array=array, format=format, filename=filename, **kwargs)


class InertRenderTexture(_Inert):
    """Stand-in for ``sapien.render.RenderTexture``."""

    def __init__(self, array: Any = None, dim: int | None = None, format: str | None = None,
                 **kwargs: Any) -> None:
        super().__init__(array=array, dim=dim, format=format, **kwargs)


_STAND_INS = {
    "RenderMaterial": InertRenderMaterial,
    "RenderTexture2D": InertRenderTexture2D,
    "RenderTexture": InertRenderTexture,
}
_installed = False
_version_checked = False


def _check_versions() -> None:
    global _version_checked
    if _version_checked:
        return
    from importlib import metadata

    _version_checked = True
    found = {}
    for dist in PINNED_VERSIONS:
        try:
            found[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            found[dist] = "not installed"
    if found != PINNED_VERSIONS:
        written = ", ".join(f"{d} {v}" for d, v in PINNED_VERSIONS.items())
        have = ", ".join(f"{d} {v}" for d, v in found.items())
        warnings.warn(
            f"simreel's no-render layer was written for {written}; found {have}. State-only envs without a "
            "render device may fail to build; install the pinned versions or a Vulkan driver.",
            NoRenderVersionWarning,
            stacklevel=3,
        )


def is_installed() -> bool:
    """Whether the stand-ins replaced sapien's classes in this process."""
    return _installed


def check_task(env_id: str) -> None:
    """Raise `RenderUnavailableError` for a task that cannot be built without a render device."""
    reason = TASKS_NEEDING_RENDER.get(env_id)
    if reason is not None:
        from simreel.sim.make import no_render_device_fix

        raise RenderUnavailableError(
            f"{env_id} cannot be built without a render device: {reason}. To build it, {no_render_device_fix()}."
        )


def install() -> bool:
    """Install the inert stand-ins if, and only if, creating a real ``RenderMaterial`` fails.

    Returns whether the stand-ins are in place. Imports sapien (call `simreel.sim.render_device.configure_vulkan`
    first). Idempotent.
    """
    global _installed
    if _installed:
        return True
    _check_versions()
    import sapien.pysapien.render as pysapien_render
    import sapien.render

    try:
        sapien.render.RenderMaterial()
    except RuntimeError:
        pass
    else:
        return False  # a render device exists; the real classes work
    real = {name: getattr(pysapien_render, name) for name in _CLASS_NAMES}
    # Every loaded module that holds one of the real classes under its own name gets the stand-in: this covers
    # sapien.render, sapien.pysapien.render, sapien.wrapper.urdf_loader, mani_skill's _mjcf_loader and user
    # modules that did `from sapien.render import RenderMaterial`. Modules imported later resolve the name
    # through sapien.render and get the stand-in anyway.
    for module in list(sys.modules.values()):
        namespace = getattr(module, "__dict__", None)
        if not isinstance(namespace, dict):
            continue
        for name, cls in real.items():
            if namespace.get(name) is cls:
                namespace[name] = _STAND_INS[name]
    _installed = True
    return True
