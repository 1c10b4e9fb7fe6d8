"""Import the user's own code (custom tasks, policies) for the CLI's ``--import``, and sapien quietly.

mani_skill (~3 s to import) and sapien are imported inside the functions here, never at module level.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import os
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

from simreel.errors import EnvBuildError
from simreel.sim.render_device import configure_vulkan

__all__ = ["import_user_code", "imported_user_code", "quiet_sapien_import"]

_IMPORTED: dict[str, str] = {}
"""Every spec `import_user_code` imported in this process, in order, and the name of the module it gave."""


@contextlib.contextmanager
def quiet_sapien_import() -> Iterator[None]:
    """Importing sapien warns that it falls back to its bundled libvulkan when the system has none;
    that is expected and fine, so simreel's imports of sapien (direct or through user code) hide it."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*libvulkan.*", category=UserWarning)
        yield


def import_user_code(spec: str) -> ModuleType:
    """Import a dotted module or a ``.py`` file, for the CLI's ``--import``: custom tasks and policies.

    A ``.py`` path is loaded as a module named after the file (its folder goes first on ``sys.path``, as when
    Python runs a script, so it can import its neighbours). A dotted name is imported normally, with the current
    folder appended to ``sys.path`` so ``--import mytasks`` finds ``./mytasks.py``. Vulkan is configured first,
    because user code usually imports mani_skill. Any failure becomes one-line `EnvBuildError`.
    """
    configure_vulkan()
    with quiet_sapien_import():
        module = _import_user_code(spec)
    _IMPORTED.setdefault(spec, module.__name__)
    return module


def imported_user_code() -> dict[str, str]:
    """The user's code this process imported (`import_user_code` spec -> module name), simreel's own modules
    left out; error messages name it (an env id none of it registers)."""
    return {spec: name for spec, name in _IMPORTED.items() if name != "simreel" and not name.startswith("simreel.")}


def _import_user_code(spec: str) -> ModuleType:
    looks_like_path = spec.endswith(".py") or os.sep in spec or (os.altsep is not None and os.altsep in spec)
    try:
        if looks_like_path:
            return _import_file(Path(spec))
        if os.getcwd() not in sys.path and "" not in sys.path:
            sys.path.append(os.getcwd())
        return importlib.import_module(spec)
    except EnvBuildError:
        raise
    except ModuleNotFoundError as exc:
        if exc.name is not None and (spec == exc.name or spec.startswith(exc.name + ".")):
            raise EnvBuildError(
                f"--import {spec}: no module named {exc.name!r} on sys.path; pass a path ending in .py to import a file"
            ) from exc
        raise EnvBuildError(f"--import {spec}: {type(exc).__name__}: {exc}") from exc
    except (Exception, SystemExit) as exc:
        message = " ".join(str(exc).split())
        raise EnvBuildError(f"--import {spec}: {type(exc).__name__}: {message}") from exc


def _import_file(path: Path) -> ModuleType:
    path = path.expanduser().resolve()
    if not path.is_file():
        raise EnvBuildError(f"--import {path}: file not found")
    name = path.stem if path.stem.isidentifier() else "simreel_user_module"
    existing = sys.modules.get(name)
    if existing is not None:
        if getattr(existing, "__file__", None) and Path(existing.__file__).resolve() == path:
            return existing
        name = f"simreel_user_{abs(hash(str(path))):x}"
    module_spec = importlib.util.spec_from_file_location(name, path)
    if module_spec is None or module_spec.loader is None:
        raise EnvBuildError(f"--import {path}: cannot be imported as a Python module")
    folder = str(path.parent)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module
    try:
        module_spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module
