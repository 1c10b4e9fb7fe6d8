"""Build ManiSkill envs the same way everywhere in simreel, on a GPU, on lavapipe or with no render device.

`make_env` is the only place simreel calls ``gym.make``. It configures Vulkan before sapien loads, picks the
render backend, switches on the no-render layer when there is no device, and turns every failure into a
`simreel.errors.SimreelError` whose one line says what went wrong and how to fix it. mani_skill (~3 s to import)
is imported inside the functions here, never at module level.
"""

from __future__ import annotations

import contextlib
import difflib
import importlib
import importlib.util
import os
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from simreel.errors import EnvBuildError, RenderUnavailableError
from simreel.render_device import configure_vulkan, probe_render_device, start_render_probe

if TYPE_CHECKING:
    import gymnasium as gym

__all__ = ["make_env", "import_user_code", "env_versions", "camera_use"]

CAMERA_TEXTURES = frozenset(
    {"rgb", "depth", "rgbd", "pointcloud", "sensor_data", "segmentation", "position", "normal", "albedo"}
)
"""Parts of an ``obs_mode`` (split on ``+``) that need cameras, hence a render device."""

_VERSIONED_DISTRIBUTIONS = {
    "simreel": "simreel",
    "mani_skill": "mani-skill",
    "sapien": "sapien",
    "torch": "torch",
    "numpy": "numpy",
    "gymnasium": "gymnasium",
}


def camera_use(obs_mode: str | None, render_mode: str | None = None) -> str | None:
    """Say why this ``obs_mode`` / ``render_mode`` needs a render device, or None if it does not."""
    if obs_mode:
        textures = sorted(set(obs_mode.split("+")) & CAMERA_TEXTURES)
        if textures:
            return f"obs_mode={obs_mode!r} needs camera images ({', '.join(textures)})"
    if render_mode is not None:
        return f"render_mode={render_mode!r} renders images"
    return None


SIMREEL_TASK_PREFIX = "Simreel"
"""Env ids of simreel's own example tasks; `make_env` registers them on first use, no --import needed."""


@contextlib.contextmanager
def _quiet_sapien_import() -> Iterator[None]:
    """Importing sapien warns that it falls back to its bundled libvulkan when the system has none;
    that is expected and fine, so simreel's imports of sapien (direct or through user code) hide it."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*libvulkan.*", category=UserWarning)
        yield


def _import_mani_skill() -> tuple[Any, dict[str, Any]]:
    """Import gymnasium and register ManiSkill's tasks; return (gymnasium, ManiSkill's env registry)."""
    import gymnasium

    with _quiet_sapien_import():
        import mani_skill.envs  # noqa: F401  (registers the built-in tasks)
    from mani_skill.utils.registration import REGISTERED_ENVS

    return gymnasium, REGISTERED_ENVS


def _unknown_env_message(env_id: str, known: list[str]) -> str:
    by_lower = {name.lower(): name for name in known}
    close = difflib.get_close_matches(env_id.lower(), list(by_lower), n=3, cutoff=0.6)
    hint = f"did you mean {', '.join(by_lower[c] for c in close)}?" if close else f"{len(known)} are registered"
    return (
        f"unknown ManiSkill env id {env_id!r}: {hint} "
        "(a custom task must be registered first: pass --import MODULE_OR_FILE.py)"
    )


def _missing_assets(spec: Any) -> list[str]:
    """Asset ids a registered task needs that are not downloaded (ManiSkill would prompt on stdin, then exit)."""
    from mani_skill.utils import assets

    missing: list[str] = []
    for asset_id in spec.asset_download_ids or []:
        if asset_id in assets.DATA_GROUPS:
            ids = assets.expand_data_group_into_individual_data_source_ids(asset_id)
        else:
            ids = [asset_id]
        missing += [i for i in ids if i in assets.DATA_SOURCES and not assets.is_data_source_downloaded(i)]
    return missing


def _resolve_render_backend(render_backend: str | None) -> tuple[str, str]:
    """Return (ManiSkill render_backend, why)."""
    if render_backend is None or render_backend == "none":
        return "none", "render_backend='none' was asked for"
    if render_backend != "auto":
        return render_backend, f"render_backend={render_backend!r} was asked for"
    probe = probe_render_device()
    return probe.backend, probe.detail


def make_env(
    env_id: str,
    *,
    num_envs: int = 1,
    obs_mode: str = "state",
    control_mode: str | None = None,
    sim_backend: str = "auto",
    render_backend: str = "auto",
    reward_mode: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    max_episode_steps: int | None = None,
    sim_config: dict[str, Any] | None = None,
) -> gym.Env:
    """Build a registered ManiSkill env with ``gym.make`` and return it.

    Args:
        env_id: a registered ManiSkill task, e.g. ``"PickCube-v1"`` (custom tasks: `import_user_code` first).
        num_envs: parallel envs; more than 1 needs the GPU sim (ManiSkill's ``sim_backend="auto"`` picks it).
        obs_mode: ManiSkill observation mode. ``"state"``/``"state_dict"``/``"none"`` need no render device;
            ``rgb``, ``depth``, ``rgbd``, ``pointcloud``, ``sensor_data``, ``segmentation`` (and ``+`` mixes) do.
        control_mode, reward_mode: ManiSkill's; None means the task's default.
        sim_backend: ``"auto"``, ``"cpu"``/``"physx_cpu"`` or ``"gpu"``/``"physx_cuda"``, passed to ManiSkill.
        render_backend: ``"auto"`` (probe: `simreel.render_device.detect_render_backend`), ``"gpu"``,
            ``"cpu"`` (software Vulkan) or ``"none"`` (state-only; `simreel.norender` is switched on).
        env_kwargs: further keyword arguments for the task, e.g. ``{"render_mode": "rgb_array"}``,
            ``{"robot_uids": "panda"}``. They may not repeat the named arguments above.
        max_episode_steps: override the task's time limit (None: the task's own).
        sim_config: ManiSkill ``SimConfig`` overrides as a dict, e.g. ``{"sim_freq": 500}``.

    Raises:
        EnvBuildError: unknown env id (with close matches), missing assets, bad kwargs (ManiSkill's own message).
        RenderUnavailableError: cameras or ``render_mode`` were asked for but there is no render device, or the
            task cannot be built without one (PushT-v1).
    """
    env_kwargs = dict(env_kwargs or {})
    named = {"num_envs", "obs_mode", "control_mode", "sim_backend", "render_backend", "reward_mode",
             "sim_config", "max_episode_steps"}
    repeated = sorted(named & set(env_kwargs))
    if repeated:
        raise EnvBuildError(
            f"{env_id}: env_kwargs repeats {', '.join(repeated)}; pass them as make_env keyword arguments instead"
        )
    render_mode = env_kwargs.get("render_mode")

    configure_vulkan()
    if render_backend == "auto":
        start_render_probe()  # runs in a child process while mani_skill imports here
    gym, registry = _import_mani_skill()

    spec = registry.get(env_id)
    if spec is None and env_id.startswith(SIMREEL_TASK_PREFIX):
        import simreel.tasks  # noqa: F401  (simreel's example tasks register on import)

        spec = registry.get(env_id)
    if spec is None:
        raise EnvBuildError(_unknown_env_message(env_id, sorted(registry)))
    missing = _missing_assets(spec)
    if missing:
        ids = " ".join(missing)
        raise EnvBuildError(
            f"{env_id} needs assets that are not downloaded: {ids}. Fetch them with "
            f"`python -m mani_skill.utils.download_asset {missing[0]}` (needs internet; MS_ASSET_DIR sets where)"
        )

    backend, why = _resolve_render_backend(render_backend)
    if backend == "none":
        needs = camera_use(obs_mode, render_mode)
        if needs is not None:
            raise RenderUnavailableError(
                f"{env_id}: {needs}, but there is no render device ({why}). Run `make setup` to fetch the "
                "software Vulkan driver (lavapipe) or use a GPU machine; or use obs_mode='state' and no render_mode."
            )
        from simreel import norender

        norender.check_task(env_id)
        norender.install()

    kwargs: dict[str, Any] = {
        **env_kwargs,
        "num_envs": num_envs,
        "obs_mode": obs_mode,
        "control_mode": control_mode,
        "reward_mode": reward_mode,
        "sim_backend": sim_backend,
        "render_backend": backend,
    }
    if sim_config is not None:
        kwargs["sim_config"] = sim_config
    if max_episode_steps is not None:
        kwargs["max_episode_steps"] = max_episode_steps
    try:
        return gym.make(env_id, **kwargs)
    except SystemExit as exc:  # ManiSkill calls exit() when asked for assets it cannot get
        raise EnvBuildError(f"{env_id}: ManiSkill exited while building the env ({exc.code})") from exc
    except Exception as exc:
        raise _build_error(env_id, exc, backend=backend, num_envs=num_envs, sim_backend=sim_backend) from exc


def _build_error(env_id: str, exc: Exception, *, backend: str, num_envs: int, sim_backend: str) -> Exception:
    message = " ".join(str(exc).split())  # one line
    if message == "failed to find a rendering device" or "ErrorIncompatibleDriver" in message:
        return RenderUnavailableError(
            f"{env_id}: render_backend={backend!r} but there is no render device. Run `make setup` to fetch "
            "the software Vulkan driver (lavapipe), or pass render_backend='auto' (or 'none' with obs_mode='state')."
        )
    if message == 'failed to find device "cuda"':
        if num_envs > 1 and sim_backend in ("auto", "gpu", "cuda", "physx_cuda"):
            return EnvBuildError(
                f"{env_id}: num_envs={num_envs} needs the GPU sim (PhysX CUDA) and this machine has no CUDA device; "
                "use num_envs=1 (CPU sim), or gymnasium's AsyncVectorEnv for several CPU envs"
            )
        return EnvBuildError(f"{env_id}: a CUDA device was asked for and this machine has none ({message})")
    if isinstance(exc, AttributeError) and "render_shapes" in message:
        return RenderUnavailableError(
            f"{env_id} reads render shapes while building its scene, which needs a render device ({message}). "
            "Run `make setup` to fetch the software Vulkan driver (lavapipe), or use a GPU machine."
        )
    return EnvBuildError(f"{env_id}: could not build the env: {type(exc).__name__}: {message}")


def import_user_code(spec: str) -> ModuleType:
    """Import a dotted module or a ``.py`` file, for the CLI's ``--import``: custom tasks and policies.

    A ``.py`` path is loaded as a module named after the file (its folder goes first on ``sys.path``, as when
    Python runs a script, so it can import its neighbours). A dotted name is imported normally, with the current
    folder appended to ``sys.path`` so ``--import mytasks`` finds ``./mytasks.py``. Vulkan is configured first,
    because user code usually imports mani_skill. Any failure becomes one-line `EnvBuildError`.
    """
    configure_vulkan()
    with _quiet_sapien_import():
        return _import_user_code(spec)


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


def env_versions() -> dict[str, str | None]:
    """Versions of simreel, mani_skill, sapien, torch, numpy, gymnasium and Python (None: not installed).

    Read from package metadata, so nothing heavy is imported.
    """
    import platform
    from importlib import metadata

    versions: dict[str, str | None] = {}
    for key, distribution in _VERSIONED_DISTRIBUTIONS.items():
        try:
            versions[key] = metadata.version(distribution)
        except metadata.PackageNotFoundError:
            versions[key] = None
    if versions["simreel"] is None:
        from simreel import __version__

        versions["simreel"] = __version__
    versions["python"] = platform.python_version()
    return versions
